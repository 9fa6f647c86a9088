"""The compose file's tester: read every device of the cell with pycomm3 and print a summary.

    python docker/tester.py /etc/enip-farm/cell.yaml
Exit status 0 only if every device answered ListIdentity and its assemblies could be read.
"""

from __future__ import annotations

import sys

from pycomm3 import CIPDriver, Services

from enip_farm.config import load_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue


def read(address: str, instance: int) -> bytes | None:
    with CIPDriver(address) as driver:
        reply = driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=instance,
                                       attribute=3, connected=False, route_path=False)
    return None if reply.error else reply.value


def main(path: str) -> int:
    failures = 0
    print(f"{'NAME':12} {'ADDRESS':16} {'PRODUCT':10} {'INPUTS':26} OUTPUTS")
    for profile in build_profiles(load_config(path), shipped_catalogue()):
        address = profile.address
        try:
            identity = CIPDriver.list_identity(CIPDriver(address), address) or {}
            inputs = read(address, 101) if profile.input_size else b""
            outputs = read(address, 100) if profile.output_size else b""
            ok = bool(identity) and inputs is not None and outputs is not None
        except Exception as error:  # one failing device must not hide the others
            identity, inputs, outputs, ok = {"product_name": f"error: {error}"}, None, None, False
        failures += not ok
        print(f"{profile.name:12} {address:16} {identity.get('product_name', '-'):10} "
              f"{(inputs or b'').hex():26} {(outputs or b'').hex()}")
    total = len(load_config(path).devices)
    print(f"{total - failures}/{total} devices answered")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "/etc/enip-farm/cell.yaml"))
