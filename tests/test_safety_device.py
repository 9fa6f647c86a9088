"""The DSQC1042 as the farm builds it: a CIP Safety target whose 12 safe inputs and 4 safe outputs
are signals like any (Python and HTTP APIs), whose safe outputs no explicit write can set, whose
Safety Supervisor answers its TUNID, and whose placeholders are listed as unverified."""

from __future__ import annotations

import inspect
import ipaddress
import struct

import httpx
from pycomm3 import CIPDriver, Services

from enip_farm.config import DeviceConfig
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.profile import resolve
from enip_farm.device.signals import SignalMap
from enip_farm.protocol.cip import decode_reply, encode_request
from enip_farm.protocol.connection import class0_data, decode_io_packet, encode_class0_packet, encode_forward_open
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.safety.crc import Seeds
from enip_farm.protocol.safety.messages import decode_time_coordination, encode_data, mode_byte
from enip_farm.protocol.safety.validator import ticks
from enip_farm.protocol.session import MessageContext
from tests.test_safety import MS, ORIGINATOR, T0, _pid, safety_open


def test_dsqc1042_profile_signals_and_placeholders() -> None:
    profile = resolve(DeviceConfig(name="s1", address="127.0.30.1", model="DSQC1042"), shipped_catalogue())
    assert (profile.input_size, profile.output_size) == (2, 1)
    assert SignalMap(profile).names() == {"DI": 12, "DO": 4, "AI": 0, "AO": 0}
    output = profile.assembly("output")
    assert output is not None and not output.settable  # the safety connection writes the safe outputs
    assert profile.safety is not None and profile.safety.node_address == 0x7F001E01
    assert {"DSQC1042.safety.snn", "DSQC1042.safety.scid", "DSQC1042.safety.null_point",
            "DSQC1042.assemblies.output", "DSQC1042.assemblies.input", "DSQC1042.io counts",
            "DSQC1042.class-1 I/O refused"} <= set(profile.unverified)
    own = resolve(DeviceConfig(name="s1", address="127.0.30.1", model="DSQC1042",
                               safety={"snn": "0102030405a6", "scid": "11" * 10}), shipped_catalogue())
    assert own.safety is not None and own.safety.snn == bytes.fromhex("0102030405a6")
    assert "DSQC1042.safety.snn" not in own.unverified and "DSQC1042.safety.scid" not in own.unverified
    plain = resolve(DeviceConfig(name="io", address="127.0.30.2", model="DSQC1030"), shipped_catalogue())
    assert plain.safety is None


def test_safe_signals_through_the_python_and_http_apis(enip_farm) -> None:
    farm = enip_farm(name="s1", model="DSQC1042", http=True)
    handle = farm["s1"]
    url = f"http://127.0.0.1:{farm.http.port}/devices/s1/io"
    handle.set(DI3=1)
    body = httpx.put(url, json={"signals": {"DI12": 1}}).json()
    assert body["signals"]["DI"] == [0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 1] and body["signals"]["DO"] == [0, 0, 0, 0]
    assert handle.inputs == b"\x04\x08" and handle.get("DI12") == 1
    assert httpx.put(url, json={"signals": {"DI13": 1}}).status_code == 422  # 12 safe inputs only
    assert {row["name"] for row in handle.signal_table()} >= {"DI1", "DI12", "DO1", "DO4"}


def test_explicit_messaging_on_a_safety_target(enip_farm) -> None:
    farm = enip_farm(name="s1", model="DSQC1042")
    address = farm["s1"].address
    with CIPDriver(address) as plc:
        write = plc.generic_message(service=Services.set_attribute_single, class_code=4, instance=100, attribute=3,
                                    request_data=b"\x0f", connected=False, route_path=False)
        tunid = plc.generic_message(service=Services.get_attribute_single, class_code=0x39, instance=1,
                                    attribute=27, connected=False, route_path=False)
        scid = plc.generic_message(service=Services.get_attribute_single, class_code=0x39, instance=1,
                                   attribute=26, connected=False, route_path=False)
        validators = plc.generic_message(service=Services.get_attribute_single, class_code=0x3A, instance=1,
                                         attribute=1, connected=False, route_path=False)
    assert "not settable" in str(write.error).lower() and farm["s1"].outputs == b"\x00"
    assert tunid.value == bytes.fromhex("000000000001") + struct.pack("<I", int(ipaddress.IPv4Address(address)))
    assert scid.value == bytes(10)
    assert validators.error  # no safety connection open: no Safety Validator instance


def test_a_time_coordination_answer_leaves_through_the_send_receive_io_requires() -> None:
    assert inspect.signature(Device.receive_io).parameters["send"].default is inspect.Parameter.empty
    device = Device(resolve(DeviceConfig(name="s1", address="127.0.77.1", model="DSQC1042"), shipped_catalogue()))
    request = safety_open()
    message = encode_request(0x54, encode_request_path(6, 1), encode_forward_open(request))
    reply, _ = device.handle_unconnected(message, MessageContext(ORIGINATOR.host, None, (), T0))
    assert decode_reply(reply).general_status == 0
    (connection,) = device.connections.values()
    sent: list[tuple[bytes, tuple[str, int]]] = []
    now = T0 + 5 * MS
    idle = encode_data(b"\x00", mode_byte(False, 0), 0, _pid(request), False)
    assert device.receive_io(encode_class0_packet(connection.o_t_id, 1, idle), (ORIGINATOR.host, 2222), now,
                             lambda data, address: sent.append((data, address)))
    (packet, address), = sent
    io = decode_io_packet(packet)
    cid = Seeds.of(75, device.profile.serial_number, connection.instance)
    assert io is not None and io.connection_id == request.t_o_connection_id and address == (ORIGINATOR.host, 2222)
    assert decode_time_coordination(class0_data(io), cid, False) == (0, ticks(now))
    assert device.counters["safety_time_coordination_sent"] == 1 and device.counters["t_o_packets"] == 1
