"""Field-by-field comparison of a captured reply with the farm's (golden testing).

Compared: the encapsulation header (command, length, session handle, status, sender context,
options); for SendRRData/SendUnitData the interface handle, timeout, the CPF item types and
lengths, and in the CIP reply the service, general status, additional status and data;
RegisterSession's body; ListIdentity's identity item field by field; anything else byte for byte.

The mask, where captured and live values legitimately differ:
- `session_handle`: compared after mapping the captured handle to the live one (the farm numbers
  its own sessions; a capture may start mid-session).
- the device's own address: when the captured device is answered by a farm device on another
  address, ListIdentity's `socket_address` is not compared, and the captured address inside CIP
  reply data (e.g. TCP/IP Interface attribute 5, as a UDINT or in network order) is replaced by the
  farm device's before comparing.
"""

from __future__ import annotations

import socket
from typing import Any

from enip_farm.protocol.cip import CipDecodeError, decode_reply
from enip_farm.protocol.commands import decode_identity_item, decode_send_data
from enip_farm.protocol.cpf import ItemType, decode_items
from enip_farm.protocol.encapsulation import Command, Frame

Difference = tuple[str, Any, Any]  # field, captured, live


def _hex(value: Any) -> Any:
    return value.hex(" ") if isinstance(value, bytes | bytearray) else value


def _address_forms(address: str) -> list[bytes]:
    network = socket.inet_aton(address)
    return [network[::-1], network]  # UDINT (little-endian) as the TCP/IP object sends it, network order


def compare_replies(captured: Frame, live: Frame, session_map: dict[int, int],
                    addresses: tuple[str, str] | None = None) -> list[Difference]:
    """`addresses`: (captured device address, farm device address) when they differ."""
    diffs: list[Difference] = []
    address_mapped = addresses is not None

    def check(name: str, a: Any, b: Any) -> None:
        if a != b:
            diffs.append((name, _hex(a), _hex(b)))

    ch, lh = captured.header, live.header
    check("encapsulation.command", ch.command, lh.command)
    check("encapsulation.status", ch.status, lh.status)
    check("encapsulation.session_handle", session_map.get(ch.session_handle, ch.session_handle), lh.session_handle)
    check("encapsulation.sender_context", ch.sender_context, lh.sender_context)
    check("encapsulation.options", ch.options, lh.options)
    check("encapsulation.length", ch.length, lh.length)
    if ch.command != lh.command or ch.status or lh.status:
        return diffs
    if ch.command in (Command.SEND_RR_DATA, Command.SEND_UNIT_DATA):
        captured_data = captured.data
        if addresses is not None:
            for old, new in zip(_address_forms(addresses[0]), _address_forms(addresses[1]), strict=True):
                captured_data = captured_data.replace(old, new)
        _compare_send_data(captured_data, live.data, check)
    elif ch.command == Command.LIST_IDENTITY:
        _compare_identity(captured.data, live.data, check, address_mapped)
    else:
        check("data", captured.data, live.data)
    return diffs


def _compare_send_data(captured: bytes, live: bytes, check) -> None:
    try:
        a, b = decode_send_data(captured), decode_send_data(live)
    except ValueError:
        check("data", captured, live)
        return
    check("send_data.interface_handle", a.interface_handle, b.interface_handle)
    check("send_data.timeout", a.timeout, b.timeout)
    check("cpf.item_count", len(a.items), len(b.items))
    for index, (x, y) in enumerate(zip(a.items, b.items, strict=False)):
        check(f"cpf.item[{index}].type", x.type_id, y.type_id)
        if x.type_id == y.type_id and x.type_id in (ItemType.UNCONNECTED_DATA, ItemType.CONNECTED_DATA):
            offset = 2 if x.type_id == ItemType.CONNECTED_DATA else 0
            if offset:
                check(f"cpf.item[{index}].sequence_count", x.data[:2], y.data[:2])
            _compare_cip(x.data[offset:], y.data[offset:], check)
        else:
            check(f"cpf.item[{index}].data", x.data, y.data)
        check(f"cpf.item[{index}].length", len(x.data), len(y.data))


def _compare_cip(captured: bytes, live: bytes, check) -> None:
    try:
        a, b = decode_reply(captured), decode_reply(live)
    except CipDecodeError:
        check("cip", captured, live)
        return
    check("cip.service", a.service, b.service)
    check("cip.general_status", a.general_status, b.general_status)
    check("cip.additional_status", a.additional_status, b.additional_status)
    check("cip.data", a.data, b.data)


def _compare_identity(captured: bytes, live: bytes, check, address_mapped: bool) -> None:
    try:
        a = decode_identity_item(decode_items(captured)[0].data)
        b = decode_identity_item(decode_items(live)[0].data)
    except (ValueError, IndexError):
        check("data", captured, live)
        return
    for name in a._fields:
        if name == "socket_address" and address_mapped:
            continue
        check(f"list_identity.{name}", getattr(a, name), getattr(b, name))
