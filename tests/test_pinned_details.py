"""Details no test pinned until mutation testing (bench/mutation.py, issue 32) changed them and every
test still passed: codes checked against a real peer's (pycomm3) rather than against themselves,
fields at offsets other than 0, bytes the spec fixes (an interface handle of 0). Each test says
which mutant it kills; bench/mutation-equivalents.md lists those no test can tell apart."""

from __future__ import annotations

from pycomm3 import ClassCode as PeerClassCode
from pycomm3 import Services as PeerServices
from pycomm3.cip import ConnectionManagerServices, EncapsulationCommands

from enip_farm.protocol.cip import ClassCode, Service
from enip_farm.protocol.commands import (
    ServiceItem,
    decode_service_item,
    encode_service_item,
    encode_unconnected_payload,
)
from enip_farm.protocol.encapsulation import Command
from enip_farm.protocol.epath import LogicalSegment, LogicalType, decode_epath

# -- protocol/: codes as a peer has them --------------------------------------------------------------


def _code(peer: bytes) -> int:
    return int.from_bytes(peer, "little")


def test_service_codes_are_pycomm3s() -> None:
    """Vol. 1, appendix A and 3-5.5: e.g. Unconnected Send 0x52 (a mutant made it 0x53)."""
    peer = {**{k: v for k, v in vars(PeerServices).items() if isinstance(v, bytes)},
            **{k: v for k, v in vars(ConnectionManagerServices).items() if isinstance(v, bytes)}}
    names = {Service.GET_ATTRIBUTES_ALL: "get_attributes_all", Service.SET_ATTRIBUTES_ALL: "set_attributes_all",
             Service.GET_ATTRIBUTE_LIST: "get_attribute_list", Service.SET_ATTRIBUTE_LIST: "set_attribute_list",
             Service.RESET: "reset", Service.MULTIPLE_SERVICE_PACKET: "multiple_service_request",
             Service.GET_ATTRIBUTE_SINGLE: "get_attribute_single", Service.SET_ATTRIBUTE_SINGLE: "set_attribute_single",
             Service.FORWARD_CLOSE: "forward_close", Service.UNCONNECTED_SEND: "unconnected_send",
             Service.FORWARD_OPEN: "forward_open", Service.LARGE_FORWARD_OPEN: "large_forward_open"}
    assert set(names) == set(Service) - {Service.GET_AND_CLEAR}  # Get_and_Clear (0x4C, Ethernet Link): not in pycomm3
    assert {service.name: int(service) for service in names} == {s.name: _code(peer[n]) for s, n in names.items()}
    assert Service.GET_AND_CLEAR == 0x4C


def test_class_codes_are_pycomm3s() -> None:
    """Vol. 1, table 5-1.1: e.g. Parameter 0x0F (a mutant made it 0x10)."""
    names = {ClassCode.IDENTITY: "identity_object", ClassCode.MESSAGE_ROUTER: "message_router",
             ClassCode.ASSEMBLY: "assembly", ClassCode.CONNECTION_MANAGER: "connection_manager",
             ClassCode.PARAMETER: "parameter", ClassCode.SAFETY_SUPERVISOR: "safety_supervisor",
             ClassCode.SAFETY_VALIDATOR: "safety_validator", ClassCode.TCP_IP_INTERFACE: "tcp_ip_interface",
             ClassCode.ETHERNET_LINK: "ethernet_link"}
    assert set(names) == set(ClassCode)
    assert {c.name: int(c) for c in names} == {c.name: _code(getattr(PeerClassCode, n)) for c, n in names.items()}


def test_encapsulation_commands_are_pycomm3s() -> None:
    """Vol. 2, table 2-3.2: e.g. ListServices 0x0004."""
    assert {c.name: int(c) for c in Command} == {
        c.name: _code(getattr(EncapsulationCommands, c.name.lower())) for c in Command}


# -- protocol/: fields at their offsets -----------------------------------------------------------------


def test_a_32_bit_logical_segment_after_an_8_bit_one() -> None:
    """Vol. 1, C-1.4.2: the 32-bit format has a pad byte, its value at offset + 2 of the segment
    (a mutant read `offset | 2`, the same at offset 0 and 4, not at 2)."""
    assert decode_epath(bytes.fromhex("20 04 26 00 78 56 34 12 30 03")) == [
        LogicalSegment(LogicalType.CLASS_ID, 4), LogicalSegment(LogicalType.INSTANCE_ID, 0x12345678),
        LogicalSegment(LogicalType.ATTRIBUTE_ID, 3)]
    assert decode_epath(bytes.fromhex("21 00 F5 00 26 00 01 00 00 80")) == [
        LogicalSegment(LogicalType.CLASS_ID, 0xF5), LogicalSegment(LogicalType.INSTANCE_ID, 0x80000001)]


def test_the_list_services_item() -> None:
    """Vol. 2, 2-4.6.3: version 1, flags (bit 5: CIP over TCP, bit 8: class 0/1 over UDP), a
    16-byte name; decoded from its first byte (a mutant read from the second)."""
    item = bytes.fromhex("0100 2001") + b"Communications\x00\x00"
    assert encode_service_item(ServiceItem(1, 0x0120, "Communications")) == item
    assert decode_service_item(item) == ServiceItem(1, 0x0120, "Communications")


def test_an_unconnected_payload_has_interface_handle_0() -> None:
    """Vol. 2, 2-4.7: interface handle 0 (CIP), then the timeout, the null address item and the
    unconnected data item (a mutant wrote handle 1)."""
    assert encode_unconnected_payload(b"\x0e\x02\x20\x01\x24\x01", timeout=5) == bytes.fromhex(
        "00000000 0500 0200 0000 0000 b200 0600 0e0220012401")
