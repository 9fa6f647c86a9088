"""Runs cm-ethernetip's own CIP Safety target (`ethernetip.safety.safety_device.SafetyDevice`)
on one loopback address, as the second reference the farm's Safety Supervisor is compared with.
Run by the python of the cm-ethernetip venv (tests/cm_ethernetip/__init__.py), never imported:

    python target.py '{"address": "127.0.20.7", "snn": "000000000001"}'

Prints {"event": "ready"} once it listens on TCP 44818 of that address (its UDP on an ephemeral
port, so that no farm's port 2222 is in the way), and stops when stdin closes."""

from __future__ import annotations

import asyncio
import ipaddress
import json
import sys

from ethernetip.cip.identity_info import IdentityInfo
from ethernetip.safety.safety_device import SafetyDevice
from ethernetip.safety.types import SafetyNetworkNumber


async def main(args: dict) -> None:
    address = args["address"]
    device = SafetyDevice(IdentityInfo(), address, SafetyNetworkNumber(bytes.fromhex(args["snn"])),
                          int(ipaddress.IPv4Address(address)))
    await device.start(udp_port=0)
    sys.stdout.write(json.dumps({"event": "ready"}) + "\n")
    sys.stdout.flush()
    loop = asyncio.get_running_loop()
    await loop.run_in_executor(None, sys.stdin.read)
    await device.close()


if __name__ == "__main__":
    asyncio.run(main(json.loads(sys.argv[1])))
