"""The compose file's tester: read every device of the cell with pycomm3 and print a summary.

    python docker/tester.py /etc/enip-farm/cell.yaml [--passes 3] [--wait SECONDS]
With --wait (an engine that starts everything at once: Swarm, Kubernetes), first send ListIdentity
to every device (`enip-farm probe`) until all answer or SECONDS pass.
For every device: ListIdentity (UDP), then its input and output assemblies (Get Attribute Single
of class 4, instances 101 and 100, over TCP). Devices that fail are tried again, up to `--passes`
passes one second apart. Exit status 0 only if every device answered all three.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

from pycomm3 import CIPDriver, Services

from enip_farm.config import load_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.profile import DeviceProfile


def read(driver: CIPDriver, instance: int) -> bytes | None:
    reply = driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=instance,
                                   attribute=3, connected=False, route_path=False)
    return None if reply.error else reply.value


def check(profile: DeviceProfile) -> tuple[bool, str]:
    """One device: (answered everything, its line of the summary)."""
    address = profile.address
    try:
        identity = CIPDriver.list_identity(address) or {}  # a classmethod taking the path
        with CIPDriver(address) as driver:
            inputs = read(driver, 101) if profile.input_size else b""
            outputs = read(driver, 100) if profile.output_size else b""
    except Exception as error:  # one failing device must not hide the others
        return False, f"{profile.name:12} {address:16} error: {error}"
    ok = bool(identity) and inputs is not None and outputs is not None
    return ok, (f"{profile.name:12} {address:16} {identity.get('product_name', '-'):10} "
                f"{'-' if inputs is None else inputs.hex():26} {'-' if outputs is None else outputs.hex()}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("config", nargs="?", default="/etc/enip-farm/cell.yaml")
    parser.add_argument("--passes", type=int, default=3)
    parser.add_argument("--wait", type=float, default=0.0, metavar="SECONDS")
    args = parser.parse_args(argv)
    deadline = time.monotonic() + args.wait
    while args.wait > 0:
        probe = subprocess.run(["enip-farm", "probe", "--config", args.config, "--timeout", "2"],
                               capture_output=True, text=True, timeout=60)
        if probe.returncode == 0 or time.monotonic() >= deadline:
            print(f"waited {args.wait - max(0.0, deadline - time.monotonic()):.0f} s: {probe.stdout.strip()}",
                  flush=True)
            break
        time.sleep(1.0)
    profiles = build_profiles(load_config(args.config), shipped_catalogue())
    lines: dict[str, str] = {}
    pending = list(profiles)
    for attempt in range(max(1, args.passes)):
        if attempt:
            time.sleep(1.0)
        failed = []
        for profile in pending:
            ok, lines[profile.name] = check(profile)
            if not ok:
                failed.append(profile)
        pending = failed
        if not pending:
            break
    print(f"{'NAME':12} {'ADDRESS':16} {'PRODUCT':10} {'INPUTS':26} OUTPUTS")
    for profile in profiles:
        print(lines[profile.name])
    total = len(profiles)
    print(f"{total - len(pending)}/{total} devices answered identity, inputs and outputs", flush=True)
    return 1 if pending else 0


if __name__ == "__main__":
    sys.exit(main())
