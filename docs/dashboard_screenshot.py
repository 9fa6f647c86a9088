"""Take docs/dashboard.png: the default cell served in-process with its HTTP API, a little life in
it (inputs set, an I/O connection from a real scanner, outputs written over CIP, a fault), and the
dashboard photographed by headless Chromium (Debian's chromium and chromium-driver, Selenium).

    python docs/dashboard_screenshot.py [-o docs/dashboard.png]

Binds the default cell's addresses (127.0.10.1-8): stop a farm serving them first.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from pycomm3 import CIPDriver, Services

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from enip_farm.config import default_config_path, load_config  # noqa: E402
from enip_farm.farm.farm import Farm  # noqa: E402
from tests.browser import chromium, open_page  # noqa: E402
from tests.scanners import scanner  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("-o", "--output", type=Path, default=Path(__file__).with_name("dashboard.png"))
    args = parser.parse_args()
    farm = Farm(load_config(default_config_path()), http=("127.0.0.1", 0))
    with farm.running_in_thread(), chromium("--hide-scrollbars", window=(1500, 1000)) as driver:
        with scanner(farm["io2"].address) as scan:  # a scanner owning io2's outputs
            open_page(driver, f"{farm.http.url}/", "io1")
            assert scan.forward_open(10, 2) == 0
            for bit in (0, 3, 4, 9):
                scan.outputs[bit] = True
            scan.conn.produce()
            farm["io1"].set({"DI1-8": [1, 0, 1, 1, 0, 0, 1, 0]})
            farm["io2"].set(DI2=1, DI16=1)
            farm["io4"].set(AI1=1200, AI2=-350, DI5=1)
            with CIPDriver(farm["io3"].address) as client:  # outputs written over CIP, as a PLC's test tool would
                client.generic_message(service=Services.set_attribute_single, class_code=4, instance=100, attribute=3,
                                       request_data=bytes.fromhex("0f00 0300"), connected=False, route_path=False)
            farm["io5"].inject("delay", delay_ms=250)
            time.sleep(2.5)  # two polls of the connection counters
            driver.save_screenshot(str(args.output))
    print(f"{args.output}: {args.output.stat().st_size} bytes")


if __name__ == "__main__":
    main()
