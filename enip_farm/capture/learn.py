"""`enip-farm learn CAPTURE -o PROFILE.yaml`: device profiles, in the catalogue's format, from a
capture of real devices: one profile per captured device, each from that device's traffic only.

Taken only from evidence in the capture (CIP Vol. 1: Identity 5-2, Assembly 5-5, Forward Open 3-5.5.2):
- identity: ListIdentity replies (UDP unicast or broadcast, or TCP), Get Attributes All and Get
  Attribute Single replies of the Identity object;
- an assembly instance's size: a successful Get Attribute Single of its data (attribute 3: the
  reply's length) or of its size (attribute 4), a Set Attribute Single of its data (the request's
  length), or a class-1 Forward Open's connection sizes (O->T minus the sequence count and 32-bit
  run/idle header, T->O minus the sequence count: modeless); read or written sizes win over
  connection sizes;
- an assembly instance's role: output if a Set Attribute Single wrote its data or a Forward Open
  consumed data on it (O->T point); input if a Forward Open produced it (T->O point);
  configuration if a Forward Open named it so; input-only heartbeat point if a Forward Open
  consumed no data on it with point-to-point T->O (with multicast T->O it may be input-only or
  listen-only: unverified).
A role without evidence gets RobotWare's usual instance (100 output, 101 input, 1 configuration) or,
when that was never captured and others were, the lowest captured instance no role took; either
way it is listed under `unverified`, as is every identity field, size and role the capture does
not give, and evidence that contradicts itself. The I/O layout (which bytes are digital, which are
analog words) is never guessed from a size: a learned model has no numbered DI/DO/AI/AO signals,
only its images and the named signals a configuration gives it (`signals:`).

A replay table holds every captured request that a device built from the learned identity and
assemblies does not implement (its model answers 0x05, 0x08 or 0x14) and that got another reply,
with that reply; matched on service, path and request data exactly.

The model is named after the product (or the name given), never after a model of the catalogue (a
learned profile does not replace a built-in model): a product named like one gets `_learned`
appended; with several devices each name also carries the device's address.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

from enip_farm import words
from enip_farm.capture.exchanges import Exchange, exchanges_of
from enip_farm.capture.packets import Packet, read_capture
from enip_farm.config import DeviceConfig
from enip_farm.device.catalogue import Catalogue, shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.profile import resolve
from enip_farm.protocol.cip import CipDecodeError, ClassCode, Service, decode_reply, decode_request
from enip_farm.protocol.cip import decode_unconnected_send as unconnected_send
from enip_farm.protocol.commands import IdentityItem, decode_identity_item, decode_send_data
from enip_farm.protocol.connection import ConnectionType, DecodeError, ForwardOpenRequest, decode_forward_open
from enip_farm.protocol.cpf import ItemType, decode_items
from enip_farm.protocol.encapsulation import ENIP_PORT, Command, decode_frame
from enip_farm.protocol.epath import (
    DataSegment,
    LogicalSegment,
    LogicalType,
    PathError,
    decode_epath,
    decode_request_path,
)
from enip_farm.protocol.session import MessageContext

_IDENTITY_FIELDS = ("vendor_id", "device_type", "product_code", "revision", "product_name", "serial_number")
_PLACEHOLDER = MappingProxyType({"vendor_id": 0, "device_type": 0, "product_code": 0, "revision": (1, 0),
                                 "product_name": "learned"})
_USUAL = MappingProxyType({"output": 100, "input": 101, "configuration": 1})  # RobotWare's usual instances
_SEQUENCE_COUNT, _RUN_IDLE_HEADER = 2, 4
_GAA = struct.Struct("<HHHBBHIB")  # Identity Get Attributes All up to the product name's length


class LearnError(ValueError):
    """A capture no profile can be learned from, or a request that cannot be met; one line."""


@dataclass(frozen=True)
class LearnedProfile:
    device: str  # the captured device's address
    name: str  # the model's name
    document: dict[str, Any]  # {"models": {name: model}}: a profile file's content
    notes: tuple[str, ...]  # the contradictions that made a value unverified

    @property
    def model(self) -> dict[str, Any]:
        return self.document["models"][self.name]


@dataclass
class _Evidence:
    """What the capture shows of one device."""

    identity: dict[str, Any] = field(default_factory=dict)
    sizes: dict[int, int] = field(default_factory=dict)  # instance -> bytes read or written
    connection_sizes: dict[int, int] = field(default_factory=dict)  # instance -> bytes, from a Forward Open
    roles: dict[str, int] = field(default_factory=dict)  # role -> instance
    unsure: set[str] = field(default_factory=set)  # roles whose evidence does not settle them
    notes: list[str] = field(default_factory=list)
    pairs: list[tuple[bytes, bytes]] = field(default_factory=list)  # CIP request and reply

    def size(self, instance: int, size: int, source: dict[int, int]) -> None:
        known = source.setdefault(instance, size)
        if known != size:
            self.notes.append(f"assembly {instance}: captured sizes {known} and {size}")

    def claim(self, role: str, instance: int, sure: bool = True) -> None:
        holder = next((r for r, i in self.roles.items() if i == instance and r != role), None)
        if holder is not None:
            self.notes.append(f"assembly {instance}: captured as {holder} and as {role}")
            self.unsure.update((holder, role))
            return
        known = self.roles.setdefault(role, instance)
        if known != instance:
            self.notes.append(f"{role} assembly: captured as {known} and as {instance}")
            self.unsure.add(role)
        elif not sure:
            self.unsure.add(role)


def _cip_pairs(exchange: Exchange) -> tuple[bytes, bytes] | None:
    """The CIP request and reply of an explicit exchange, unwrapped from Unconnected Send."""
    if exchange.reply is None or exchange.request.header.command not in (Command.SEND_RR_DATA, Command.SEND_UNIT_DATA):
        return None
    try:
        request_items = decode_send_data(exchange.request.data).items
        reply_items = decode_send_data(exchange.reply.data).items
    except ValueError:
        return None
    request = next((i.data for i in request_items if i.type_id in (ItemType.UNCONNECTED_DATA, ItemType.CONNECTED_DATA)),
                   None)
    reply = next((i.data for i in reply_items if i.type_id in (ItemType.UNCONNECTED_DATA, ItemType.CONNECTED_DATA)),
                 None)
    if request is None or reply is None:
        return None
    if exchange.request.header.command == Command.SEND_UNIT_DATA:
        request, reply = request[2:], reply[2:]  # the sequence count
    try:
        if (request[0] == Service.UNCONNECTED_SEND
                and decode_request_path(decode_request(request).path)[:2] == (ClassCode.CONNECTION_MANAGER, 1)):
            request = unconnected_send(decode_request(request).data).message
    except (CipDecodeError, PathError, IndexError):
        pass
    return request, reply


def _identity_from_gaa(data: bytes, identity: dict[str, Any]) -> None:
    if len(data) < _GAA.size or len(data) < _GAA.size + data[_GAA.size - 1]:
        return
    vendor, device_type, product, major, minor, _status, serial, length = _GAA.unpack_from(data)
    identity.update(vendor_id=vendor, device_type=device_type, product_code=product, revision=[major, minor],
                    serial_number=serial, product_name=data[_GAA.size : _GAA.size + length].decode("latin-1"))


def _identity_from_item(item: IdentityItem, identity: dict[str, Any]) -> None:
    identity.update(vendor_id=item.vendor_id, device_type=item.device_type, product_code=item.product_code,
                    revision=[item.revision_major, item.revision_minor], serial_number=item.serial_number,
                    product_name=item.product_name)


def _identity_attribute(attribute: int, data: bytes, identity: dict[str, Any]) -> None:
    if attribute in (1, 2, 3) and len(data) >= 2:
        identity[("vendor_id", "device_type", "product_code")[attribute - 1]] = struct.unpack_from("<H", data)[0]
    elif attribute == 4 and len(data) >= 2:  # revision: major, minor
        identity["revision"] = list(data[:2])
    elif attribute == 6 and len(data) >= 4:
        identity["serial_number"] = struct.unpack_from("<I", data)[0]
    elif attribute == 7 and data and len(data) > data[0]:
        identity["product_name"] = data[1 : 1 + data[0]].decode("latin-1")


def _list_identity(data: bytes) -> IdentityItem | None:
    try:
        return decode_identity_item(decode_items(data)[0].data)
    except (ValueError, IndexError, struct.error):
        return None


def _identity_replies(packets: list[Packet]) -> dict[str, IdentityItem]:
    """ListIdentity replies over UDP by the address that sent them (a broadcast request's replies
    pair with no request, so they are read here rather than from the exchanges)."""
    replies: dict[str, IdentityItem] = {}
    for packet in packets:
        if packet.proto != "udp" or packet.sport != ENIP_PORT:
            continue
        try:
            frame = decode_frame(packet.payload)
        except ValueError:
            continue
        if frame.header.command == Command.LIST_IDENTITY and frame.header.status == 0:
            item = _list_identity(frame.data)
            if item is not None:
                replies[packet.src] = item
    return replies


def _observe(exchange: Exchange, evidence: _Evidence) -> None:
    if exchange.request.header.command == Command.LIST_IDENTITY and exchange.reply is not None:
        item = _list_identity(exchange.reply.data)
        if item is not None:
            _identity_from_item(item, evidence.identity)
        return
    cip = _cip_pairs(exchange)
    if cip is None:
        return
    evidence.pairs.append(cip)
    try:
        request, reply = decode_request(cip[0]), decode_reply(cip[1])
        path = decode_request_path(request.path)
    except (CipDecodeError, PathError):
        return
    if reply.general_status != 0:
        return
    service, class_id = request.service, path.class_id
    if class_id == ClassCode.IDENTITY and path.instance_id == 1:
        if service == Service.GET_ATTRIBUTES_ALL:
            _identity_from_gaa(reply.data, evidence.identity)
        elif service == Service.GET_ATTRIBUTE_SINGLE and path.attribute_id:
            _identity_attribute(path.attribute_id, reply.data, evidence.identity)
    elif class_id == ClassCode.ASSEMBLY and path.instance_id and path.attribute_id == 3:
        if service == Service.GET_ATTRIBUTE_SINGLE:
            evidence.size(path.instance_id, len(reply.data), evidence.sizes)
        elif service == Service.SET_ATTRIBUTE_SINGLE:
            evidence.size(path.instance_id, len(request.data), evidence.sizes)
            evidence.claim("output", path.instance_id)
    elif (class_id == ClassCode.ASSEMBLY and path.instance_id and path.attribute_id == 4
          and service == Service.GET_ATTRIBUTE_SINGLE and len(reply.data) >= 2):
        evidence.size(path.instance_id, struct.unpack_from("<H", reply.data)[0], evidence.sizes)
    elif class_id == ClassCode.CONNECTION_MANAGER and service in (Service.FORWARD_OPEN, Service.LARGE_FORWARD_OPEN):
        try:
            forward_open = decode_forward_open(request.data, service == Service.LARGE_FORWARD_OPEN)
        except DecodeError:
            return
        _observe_forward_open(forward_open, evidence)


def _observe_forward_open(request: ForwardOpenRequest, evidence: _Evidence) -> None:
    """A successful class-1 Forward Open: its points' roles and sizes."""
    if request.transport_class != 1:
        return
    try:
        segments = decode_epath(request.connection_path)
    except PathError:
        return
    points = [s.value for s in segments if isinstance(s, LogicalSegment)
              and s.type in (LogicalType.INSTANCE_ID, LogicalType.CONNECTION_POINT)]
    configuration_data = next((s.data for s in segments if isinstance(s, DataSegment)), None)
    if len(points) == 3:
        evidence.claim("configuration", points[0])
        if configuration_data is not None:
            evidence.size(points[0], len(configuration_data), evidence.connection_sizes)
        points = points[1:]
    if len(points) != 2:
        return
    consumed, produced = points
    o_t, t_o = request.o_t_parameters, request.t_o_parameters
    data = o_t.size - _SEQUENCE_COUNT - _RUN_IDLE_HEADER
    if o_t.connection_type != ConnectionType.NULL and data > 0:
        evidence.claim("output", consumed)
        evidence.size(consumed, data, evidence.connection_sizes)
    elif t_o.connection_type == ConnectionType.POINT_TO_POINT:
        evidence.claim("input_only", consumed)  # listen-only connections take multicast T->O
    elif "input_only" not in evidence.roles or evidence.roles["input_only"] == consumed:
        evidence.claim("input_only", consumed, sure=False)
    else:
        evidence.claim("listen_only", consumed, sure=False)
    evidence.claim("input", produced)
    evidence.size(produced, max(t_o.size - _SEQUENCE_COUNT, 0), evidence.connection_sizes)


def _devices(groups: list[list[Exchange]], identities: dict[str, IdentityItem]) -> list[str]:
    """The captured devices in the order they first appear: TCP servers, then UDP answerers."""
    devices = [group[0].device for group in groups if group and group[0].transport == "tcp"]
    devices += [e.device for group in groups for e in group if e.transport == "udp" and e.reply is not None]
    devices += list(identities)
    return list(dict.fromkeys(devices))


def learn(capture: str | Path, name: str | None = None, catalogue: Catalogue | None = None,
          device: str | None = None) -> list[LearnedProfile]:
    """One profile per device of `capture` (only `device`'s if given), in the order they appear.
    `catalogue` (default: the shipped one) holds the names a model must not take. Raises
    CaptureError (a ValueError) for a file that is not a readable capture, LearnError for a capture
    without EtherNet/IP traffic, a device it does not hold, or a name the catalogue has."""
    catalogue = shipped_catalogue() if catalogue is None else catalogue
    if name is not None and name in catalogue.models:
        raise LearnError(f"{name!r} is a model of the catalogue: a learned profile never replaces one, "
                         "choose another name")
    read = read_capture(capture)
    packets = read.packets
    groups = exchanges_of(packets)
    identities = _identity_replies(packets)
    devices = _devices(groups, identities)
    if not devices:
        raise LearnError(f"{capture}: no EtherNet/IP traffic on port {ENIP_PORT} in {len(packets)} packets")
    if device is not None:
        if device not in devices:
            raise LearnError(f"{capture}: no device {device}; the capture holds {', '.join(devices)}")
        devices = [device]
    if name is not None and len(devices) > 1:
        raise LearnError(f"{capture} holds {len(devices)} devices ({', '.join(devices)}): "
                         "--name names one, choose it with --device")
    profiles: list[LearnedProfile] = []
    taken = set(catalogue.models)
    for address in devices:
        evidence = _Evidence()
        for group in groups:
            for exchange in group:
                if exchange.device == address:
                    _observe(exchange, evidence)
        if address in identities and not evidence.identity:
            _identity_from_item(identities[address], evidence.identity)
        profile = _profile(Path(capture).name, address, evidence, name, len(devices) > 1, taken, catalogue)
        if read.damaged:
            profile = replace(profile, notes=(*profile.notes, f"{read.damaged} damaged frame"
                                          f"{'s' if read.damaged > 1 else ''} of the capture skipped (dpkt could "
                                          "not decode them): what they held is not learned"))
        taken.add(profile.name)
        profiles.append(profile)
    return profiles


def _assemblies(evidence: _Evidence) -> tuple[dict[str, int], dict[str, int], list[str]]:
    """Instance and size of each role, and what of them is unverified."""
    unverified: list[str] = []
    ids = {role: evidence.roles[role] for role in _USUAL if role in evidence.roles}
    captured = sorted(set(evidence.sizes) | set(evidence.connection_sizes))
    for role, usual in _USUAL.items():
        if role in ids:
            continue
        spare = [i for i in captured if i not in ids.values()]
        ids[role] = usual if usual in spare or not spare or role == "configuration" else spare[0]
        unverified.append(f"assemblies.{role}")
    unverified += [f"assemblies.{role}" for role in sorted(evidence.unsure) if f"assemblies.{role}" not in unverified]
    sizes: dict[str, int] = {}
    for role in _USUAL:
        instance = ids[role]
        size = evidence.sizes.get(instance, evidence.connection_sizes.get(instance))
        if size is None:
            unverified.append(f"sizes.{role}")
        elif instance in evidence.sizes and evidence.connection_sizes.get(instance, size) != size:
            evidence.notes.append(f"assembly {instance}: read or written {size} bytes, connection sized for "
                                  f"{evidence.connection_sizes[instance]}")
            unverified.append(f"sizes.{role}")
        sizes[role] = size or 0
    for role in ("input_only", "listen_only"):
        if role in evidence.roles:
            ids[role] = evidence.roles[role]
    return ids, sizes, unverified


def _profile(capture: str, address: str, evidence: _Evidence, name: str | None, several: bool, taken: set[str],
             catalogue: Catalogue) -> LearnedProfile:
    unverified = [f"identity.{f}" for f in _IDENTITY_FIELDS if f not in evidence.identity and f != "serial_number"]
    identity = {**_PLACEHOLDER, "revision": list(_PLACEHOLDER["revision"]), **evidence.identity}
    assemblies, sizes, unverified_assemblies = _assemblies(evidence)
    unverified += unverified_assemblies + ["io layout"]
    model_name = (name or words.model_name(str(identity["product_name"])) or "learned") + (
        "_" + address.replace(".", "_") if several else "")
    while model_name in taken:
        model_name += "_learned"
    model: dict[str, Any] = {
        "kind": "base",
        "description": f"learned from {capture} (device {address})",
        "identity": identity,
        "assemblies": assemblies,
        "sizes": sizes,
        "io": {},
        "unverified": unverified,
        "replay": _replay_table(model_name, model_shell(identity, assemblies, sizes), evidence.pairs, catalogue),
    }
    return LearnedProfile(address, model_name, {"models": {model_name: model}}, tuple(dict.fromkeys(evidence.notes)))


def model_shell(identity: dict, assemblies: dict, sizes: dict) -> dict:
    return {"kind": "base", "description": "learning", "identity": identity, "assemblies": assemblies,
            "sizes": sizes, "io": {}}


def _replay_table(name: str, shell: dict, pairs: list[tuple[bytes, bytes]],
                  catalogue: Catalogue) -> list[dict[str, Any]]:
    """Captured requests the model would not implement, with their captured replies."""
    learning = catalogue.with_models(Catalogue.from_document({"models": {name: shell}}).models, "learning")
    device = Device(resolve(DeviceConfig(name="learning", address="127.0.0.1", model=name), learning))
    context = MessageContext("127.0.0.1", object(), (), time.monotonic_ns())  # offline: the time matters not
    table, seen = [], set()
    for request, captured in pairs:
        modelled, _ = device.handle_unconnected(request, context)
        if modelled == captured or modelled[2:3] not in (b"\x05", b"\x08", b"\x14"):
            continue
        try:
            parsed = decode_request(request)
        except CipDecodeError:
            continue
        key = (parsed.service, parsed.path, parsed.data)
        if key in seen:
            continue
        seen.add(key)
        table.append({"service": parsed.service, "path": parsed.path.hex(), "data": parsed.data.hex(),
                      "reply": captured.hex()})
    return table
