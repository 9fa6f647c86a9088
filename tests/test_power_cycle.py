"""Resetting or power-cycling a device by hand, as a test engineer does on the bench (issue 22,
item 3): the HTTP API (`POST /devices/{name}/reset`), the CLI (`enip-farm reset`) and the Python
API (`farm[name].reset()`): the TCP connections drop, the CIP connections close, the device
answers nothing for its reset time and then answers again; a second reset meanwhile gets 409.
And what survives a farm restart with its state file (item 1)."""

from __future__ import annotations

import os
import socket
import subprocess

import httpx
import pytest
from pycomm3 import CIPDriver, CommError, Services

from enip_farm.config import ConfigError
from enip_farm.farm.farm import Farm
from enip_farm.protocol.cip import encode_request
from enip_farm.protocol.epath import encode_request_path
from tests.cm_ethernetip import node_address
from tests.helpers import CLI, ENIP_PORT, RawClient, wait_for
from tests.test_cip_services import answers

pytestmark = pytest.mark.system
RESET_TIME_S = 1.0


def _identity_state(address: str) -> bytes:
    with CIPDriver(address) as driver:
        return driver.generic_message(service=Services.get_attribute_single, class_code=1, instance=1, attribute=8,
                                      connected=False, route_path=False).value


def _refused(address: str) -> bool:
    try:
        socket.create_connection((address, ENIP_PORT), timeout=1).close()
    except ConnectionRefusedError:
        return True
    return False


def test_inside_a_power_cycle_the_device_is_self_testing_refuses_and_its_sessions_are_gone(enip_farm) -> None:
    """The window (60 s) outlasts every assertion, however slow the machine: none is skipped."""
    farm = enip_farm(name="io1", model="DSQC1030", reset_time_s=60, http=True)
    address, url = farm["io1"].address, f"http://127.0.0.1:{farm.http.port}/devices/io1/reset"
    driver = CIPDriver(address)
    driver.open()
    try:
        reply = httpx.post(url, json={"type": 0})
        assert reply.status_code == 200 and reply.json() == {"device": "io1", "type": 0, "reset_time_s": 60}
        assert httpx.post(url, json={"type": 0}).status_code == 409  # resetting already
        assert httpx.get(url.removesuffix("/reset")).json()["identity"]["state"] == 1  # self testing (attribute 8)
        assert wait_for(lambda: _refused(address), timeout=10)  # no listener (it stops once the reply went out)
        with pytest.raises(CommError, match="^failed to receive reply$"):  # its session ended with the power cycle
            driver.generic_message(service=Services.get_attribute_single, class_code=1, instance=1, attribute=1,
                                   connected=False, route_path=False)
        assert _refused(address) and httpx.get(url.removesuffix("/reset")).json()["identity"]["state"] == 1
    finally:
        try:
            driver.close()
        except CommError:
            pass
    assert [e.kind for e in farm["io1"].events() if e.kind.startswith("reset")] == ["reset"]


def test_a_power_cycle_ends_on_time_and_the_device_answers_again(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", reset_time_s=RESET_TIME_S, http=True)
    address, url = farm["io1"].address, f"http://127.0.0.1:{farm.http.port}/devices/io1/reset"
    reply = httpx.post(url, json={"type": 0})
    assert reply.status_code == 200 and reply.json() == {"device": "io1", "type": 0, "reset_time_s": RESET_TIME_S}
    assert wait_for(lambda: farm["io1"].events("reset done"), timeout=RESET_TIME_S + 10)
    began, done = farm["io1"].events("reset")[0].monotonic_ns, farm["io1"].events("reset done")[0].monotonic_ns
    assert RESET_TIME_S * 1e9 <= done - began <= (RESET_TIME_S + 3.0) * 1e9  # the window: not shorter, not much longer
    assert wait_for(lambda: answers(address), timeout=10)  # listening again after the window
    assert [e.kind for e in farm["io1"].events() if e.kind.startswith("reset")] == ["reset", "reset done"]
    assert farm["io1"].events("reset")[0].text == "type 0 (power cycle): not answering for 1 s"
    assert _identity_state(address) == b"\x03"
    shown = httpx.get(url.removesuffix("/reset")).json()
    assert shown["identity"]["state"] == 3 and shown["restarts"] == 1
    assert httpx.post(url, json={"type": 3}).status_code == 422


def test_reset_type_2_from_the_cli_and_the_python_api_clears_the_safety_configuration(
        enip_farm, tmp_path) -> None:
    farm = enip_farm(name="s1", model="DSQC1042", reset_time_s=0.3, http=True,
                     safety={"scid": "11" * 10})
    address = farm["s1"].address
    env = {**os.environ, "ENIP_FARM_API": f"http://127.0.0.1:{farm.http.port}"}
    result = subprocess.run([*CLI, "reset", "s1", "--type", "2"], capture_output=True, text=True, env=env, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "s1: reset type 2, answering again in 0.3 s"
    assert wait_for(lambda: answers(address), timeout=10)
    with CIPDriver(address) as driver:
        scid = driver.generic_message(service=Services.get_attribute_single, class_code=0x39, instance=1,
                                      attribute=26, connected=False, route_path=False).value
        tunid = driver.generic_message(service=Services.get_attribute_single, class_code=0x39, instance=1,
                                       attribute=27, connected=False, route_path=False).value
    assert scid == bytes(10)  # the safety configuration is gone, the TUNID stays
    assert tunid == bytes.fromhex("000000000001") + node_address(address).to_bytes(4, "little")
    assert farm["s1"].events("reset")[0].text == (
        "type 2 (out-of-box configuration but the communication parameters): not answering for 0.3 s")
    assert wait_for(lambda: farm["s1"].reset(0), timeout=10)  # the Python API, once answering again
    assert farm["s1"].events("reset")[-1].text == "type 0 (power cycle): not answering for 0.3 s"
    failed = subprocess.run([*CLI, "reset", "s1", "--type", "5"], capture_output=True, text=True, env=env, timeout=60)
    assert failed.returncode == 2


def _supervisor(address: str, service: int, data: bytes = b"", attribute: int | None = None) -> tuple[int, bytes]:
    path = encode_request_path(0x39, 1, attribute) if attribute else encode_request_path(0x39, 1)
    with RawClient(address) as client:
        client.register()
        reply = client.request(encode_request(service, path, data))
    return reply.general_status, reply.data


def test_a_tunid_and_a_configuration_survive_a_farm_restart_with_its_state_file(free_address, tmp_path) -> None:
    address, state = free_address(), tmp_path / "state.json"
    config = {"devices": [{"name": "s1", "address": address, "model": "DSQC1042"}], "discovery": False}
    tunid = bytes.fromhex("0000000000b7") + node_address(address).to_bytes(4, "little")
    with Farm(config, state=state).running_in_thread():
        assert _supervisor(address, 0x56, tunid)[0] == 0 and _supervisor(address, 0x57, tunid)[0] == 0
    with Farm(config, state=state).running_in_thread():  # restarted with its state
        assert _supervisor(address, 0x0E, attribute=27) == (0, tunid)
    with Farm(config).running_in_thread():  # a farm without the file starts from its configuration
        assert _supervisor(address, 0x0E, attribute=27)[1] == bytes.fromhex("000000000001") + tunid[6:]
    state.write_text("[]")
    with pytest.raises(ConfigError, match="state file: .*not an enip-farm state file"):
        Farm(config, state=state)
