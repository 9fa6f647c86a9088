"""Take docs/dashboard.png: the default cell served in-process with its HTTP API, a little life in
it (inputs set, an I/O connection from a real scanner, outputs written over CIP, a fault), and the
dashboard photographed by headless Chromium (Debian's chromium and chromium-driver, Selenium).

    python docs/dashboard_screenshot.py [-o docs/dashboard.png]

Binds the default cell's addresses (127.0.10.1-8): stop a farm serving them first.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import ethernetip
from pycomm3 import CIPDriver, Services
from selenium import webdriver
from selenium.webdriver.chrome.service import Service

from enip_farm.config import default_config_path, load_config
from enip_farm.farm import Farm

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--window-size=1500,1000", "--hide-scrollbars"]


def until(condition, what: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        time.sleep(0.05)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("-o", "--output", type=Path, default=Path(__file__).with_name("dashboard.png"))
    args = parser.parse_args()
    farm = Farm(load_config(default_config_path()), http=("127.0.0.1", 0))
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in FLAGS:
        options.add_argument(flag)
    profile = tempfile.mkdtemp(prefix="enip-farm-shot-")
    options.add_argument(f"--user-data-dir={profile}")
    with farm.running_in_thread():
        driver = webdriver.Chrome(options=options, service=Service("/usr/bin/chromedriver"))
        enip = ethernetip.EtherNetIP(farm["io2"].address)  # a scanner owning io2's outputs
        conn = enip.explicit_conn(farm["io2"].address)
        try:
            driver.get(f"{farm.http.url}/")
            until(lambda: driver.execute_script("return document.getElementById('stream').textContent === 'live'"
                                                " && document.querySelectorAll('.card [data-signal]').length > 0"),
                  "the page")
            assert conn.registerSession() == 0
            enip.registerAssembly(ethernetip.EtherNetIP.ENIP_IO_TYPE_INPUT, 2, 101, conn)
            outputs = enip.registerAssembly(ethernetip.EtherNetIP.ENIP_IO_TYPE_OUTPUT, 2, 100, conn)
            enip.startIO(udp_port=0)
            assert conn.sendFwdOpenReq(101, 100, 1, torpi=10, otrpi=10, multiplier=2,
                                       originator_udp_port=enip.originator_udp_port) == 0
            for bit in (0, 3, 4, 9):
                outputs[bit] = True
            conn.produce()
            farm["io1"].set({"DI1-8": [1, 0, 1, 1, 0, 0, 1, 0]})
            farm["io2"].set(DI2=1, DI16=1)
            farm["io4"].set(AI1=1200, AI2=-350, DI5=1)
            with CIPDriver(farm["io3"].address) as client:  # outputs written over CIP, as a PLC's test tool would
                client.generic_message(service=Services.set_attribute_single, class_code=4, instance=100, attribute=3,
                                       request_data=bytes.fromhex("0f00 0300"), connected=False, route_path=False)
            farm["io5"].inject("delay", delay_ms=250)
            time.sleep(2.5)  # two polls of the connection counters
            driver.save_screenshot(str(args.output))
        finally:
            conn.stopProduce()
            enip.stopIO()
            driver.quit()
            shutil.rmtree(profile, ignore_errors=True)
    print(f"{args.output}: {args.output.stat().st_size} bytes")


if __name__ == "__main__":
    main()
