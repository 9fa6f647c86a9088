"""The cell `enip-farm golden` serves for itself (cli/captures.py imports this module when golden
runs, so that the command line's start does not pay for the farm's imports)."""

from __future__ import annotations

import os
from contextlib import ExitStack
from ipaddress import IPv4Address

from enip_farm.cli.cell import make_farm
from enip_farm.config import DeviceConfig, FarmConfig
from enip_farm.device.profile import DeviceProfile
from enip_farm.farm.farm import BindError, Farm
from enip_farm.farm.loopback import LoopbackPool


def own_farm(stack: ExitStack, config: FarmConfig) -> Farm:
    """The cell served from a thread for golden, on its own addresses; where a farm already serves
    one of them (the README's running cell) or one is not this host's (a controller's, imported
    from its EIO.cfg), on fresh loopback addresses of a block of this
    process's instead, with what a device derives from its address (serial number, MAC, safety
    node address) kept: golden maps the captured device's address to wherever the device answers,
    so the replies compared are the same."""
    config = config.model_copy(update={"discovery": False})  # golden replays to each device's own address
    first = farm = make_farm(config)
    for attempt in range(6):
        try:
            stack.enter_context(farm.running_in_thread())
            return farm
        except BindError as error:
            if not ("already in use" in str(error) or "not assigned" in str(error)) or attempt == 5:
                raise  # only golden's farm serves there: a controller's addresses need not be this host's
        addresses = LoopbackPool(214 + (os.getpid() + attempt) % 40)  # another process may hold one: the next
        farm = make_farm(config.model_copy(update={"devices": [
            _moved(device, first.devices[device.name].profile, addresses()) for device in config.devices]}))
    raise AssertionError("unreachable")


def _moved(device: DeviceConfig, profile: DeviceProfile, address: str) -> DeviceConfig:
    """The device on another address, answering with the identity it has on its own."""
    safety = device.safety
    if profile.safety is not None:
        safety = safety.model_copy(update={"node_address": profile.safety.node_address})
    return device.model_copy(update={
        "address": IPv4Address(address), "mac": ":".join(f"{b:02x}" for b in profile.mac), "safety": safety,
        "identity": device.identity.model_copy(update={"serial_number": profile.serial_number})})
