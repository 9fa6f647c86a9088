"""Field-by-field comparison of a captured reply with the farm's (golden testing).

Compared: the encapsulation header (command, length, session handle, status, sender context,
options); for SendRRData/SendUnitData the interface handle, timeout, the CPF item types and
lengths, and in the CIP reply the service, general status, additional status and data;
RegisterSession's body; ListIdentity's identity item field by field; anything else byte for byte.

The mask, where captured and live values legitimately differ (`ReplayMap`):
- `session_handle`: compared after mapping the captured handle to the live one (the farm numbers
  its own sessions; a capture may start mid-session).
- connections (Forward Open and Forward Close, Vol. 1 3-5.5.2 and 3-5.5.3; SendUnitData, Vol. 2
  2-4): the connection ids the target chose (O->T, and T->O of a multicast connection) are
  compared after mapping the captured id to the farm's; the connection triad golden sent in place
  of the captured one (a fresh connection serial) is mapped back. Sequence counts are sent as captured, so the farm's
  echo of each is compared as it is.
- the device's own address: when the captured device is answered by a farm device on another
  address, ListIdentity's `socket_address` is not compared, and the captured address inside CIP
  reply data (e.g. TCP/IP Interface attribute 5, as a UDINT or in network order) is replaced by the
  farm device's before comparing.
"""

from __future__ import annotations

import socket
import struct
from dataclasses import dataclass, field
from typing import Any

from enip_farm.protocol.cip import REPLY_BIT, CipDecodeError, MessageRouterReply, Service, decode_reply
from enip_farm.protocol.commands import decode_identity_item, decode_send_data
from enip_farm.protocol.connection import ConnectionTriad, decode_forward_open_reply
from enip_farm.protocol.cpf import ItemType, decode_items
from enip_farm.protocol.encapsulation import Command, Frame

Difference = tuple[str, Any, Any]  # field, captured, live
_FORWARD_OPEN_REPLIES = (Service.FORWARD_OPEN | REPLY_BIT, Service.LARGE_FORWARD_OPEN | REPLY_BIT)
_FORWARD_CLOSE_REPLY = Service.FORWARD_CLOSE | REPLY_BIT
_TRIAD = struct.Struct("<HHI")


@dataclass
class ReplayMap:
    """Captured values and their live counterparts in one replayed stream."""

    sessions: dict[int, int] = field(default_factory=dict)  # captured session handle -> the farm's
    o_t_ids: dict[int, int] = field(default_factory=dict)  # captured O->T connection id -> the farm's
    t_o_ids: dict[int, int] = field(default_factory=dict)  # captured T->O connection id -> the farm's
    sent_t_o_ids: set[int] = field(default_factory=set)  # T->O ids Forward Opens proposed (echoed when point to point)
    triads: dict[ConnectionTriad, ConnectionTriad] = field(default_factory=dict)  # captured -> the one sent
    adopted: list[ConnectionTriad] = field(default_factory=list)  # opened by golden, not yet closed by the capture

    def triad(self, captured: ConnectionTriad) -> ConnectionTriad:
        return self.triads.get(captured, captured)


def _hex(value: Any) -> Any:
    return value.hex(" ") if isinstance(value, bytes | bytearray) else value


def _address_forms(address: str) -> list[bytes]:
    network = socket.inet_aton(address)
    return [network[::-1], network]  # UDINT (little-endian) as the TCP/IP object sends it, network order


def compare_replies(captured: Frame, live: Frame, mapping: ReplayMap,
                    addresses: tuple[str, str] | None = None) -> list[Difference]:
    """`mapping` is updated with the connection ids a Forward Open reply gives; `addresses`:
    (captured device address, farm device address) when they differ."""
    diffs: list[Difference] = []
    address_mapped = addresses is not None

    def check(name: str, a: Any, b: Any) -> None:
        if a != b:
            diffs.append((name, _hex(a), _hex(b)))

    ch, lh = captured.header, live.header
    check("encapsulation.command", ch.command, lh.command)
    check("encapsulation.status", ch.status, lh.status)
    check("encapsulation.session_handle", mapping.sessions.get(ch.session_handle, ch.session_handle),
          lh.session_handle)
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
        _compare_send_data(captured_data, live.data, check, mapping)
    elif ch.command == Command.LIST_IDENTITY:
        _compare_identity(captured.data, live.data, check, address_mapped)
    else:
        check("data", captured.data, live.data)
    return diffs


def _compare_send_data(captured: bytes, live: bytes, check, mapping: ReplayMap) -> None:
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
            _compare_cip(x.data[offset:], y.data[offset:], check, mapping)
        elif x.type_id == y.type_id == ItemType.CONNECTED_ADDRESS and len(x.data) == len(y.data) == 4:
            captured_id = int.from_bytes(x.data, "little")  # the T->O connection id
            check(f"cpf.item[{index}].connection_id", mapping.t_o_ids.get(captured_id, captured_id),
                  int.from_bytes(y.data, "little"))
        else:
            check(f"cpf.item[{index}].data", x.data, y.data)
        check(f"cpf.item[{index}].length", len(x.data), len(y.data))


def _compare_cip(captured: bytes, live: bytes, check, mapping: ReplayMap) -> None:
    try:
        a, b = decode_reply(captured), decode_reply(live)
    except CipDecodeError:
        check("cip", captured, live)
        return
    check("cip.service", a.service, b.service)
    check("cip.general_status", a.general_status, b.general_status)
    check("cip.additional_status", a.additional_status, b.additional_status)
    if a.service == b.service and a.service in _FORWARD_OPEN_REPLIES and a.general_status == b.general_status == 0:
        _compare_forward_open(a, b, check, mapping)
    elif a.service == b.service and a.service in (*_FORWARD_OPEN_REPLIES, _FORWARD_CLOSE_REPLY) \
            and len(a.data) >= 8 and len(b.data) >= 8:
        # a Forward Close reply, or a refused Forward Open: the triad first, then sizes
        triad = mapping.triad(ConnectionTriad(*_TRIAD.unpack_from(a.data)))
        check("cip.data", _TRIAD.pack(*triad) + a.data[_TRIAD.size:], b.data)
    else:
        check("cip.data", a.data, b.data)


def _compare_forward_open(captured: MessageRouterReply, live: MessageRouterReply, check,
                          mapping: ReplayMap) -> None:
    try:
        a, b = decode_forward_open_reply(captured.data), decode_forward_open_reply(live.data)
    except struct.error:
        check("cip.data", captured.data, live.data)
        return
    check("forward_open.o_t_connection_id", mapping.o_t_ids.setdefault(a.o_t_connection_id, b.o_t_connection_id),
          b.o_t_connection_id)
    if a.t_o_connection_id in mapping.sent_t_o_ids:  # the originator's own id, echoed: compared as it is
        check("forward_open.t_o_connection_id", a.t_o_connection_id, b.t_o_connection_id)
    else:  # a multicast T->O id the target chose
        check("forward_open.t_o_connection_id",
              mapping.t_o_ids.setdefault(a.t_o_connection_id, b.t_o_connection_id), b.t_o_connection_id)
    triad = mapping.triad(a.triad)
    check("forward_open.connection_serial", triad.connection_serial, b.triad.connection_serial)
    check("forward_open.originator_vendor_id", triad.originator_vendor_id, b.triad.originator_vendor_id)
    check("forward_open.originator_serial", triad.originator_serial, b.triad.originator_serial)
    check("forward_open.o_t_api", a.o_t_api, b.o_t_api)
    check("forward_open.t_o_api", a.t_o_api, b.t_o_api)
    check("forward_open.application_reply", a.application_reply, b.application_reply)
    check("cip.data.length", len(captured.data), len(live.data))


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
