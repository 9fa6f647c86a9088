"""`enip-farm learn CAPTURE -o PROFILE.yaml`: a device profile, in the catalogue's format, from a
capture of a real device.

- Identity from ListIdentity replies, or Get Attributes All / Get Attribute Single replies of the
  Identity object.
- Assembly instances and sizes from Get/Set Attribute Single on attribute 3 (a Set marks the output
  assembly; attribute 4 gives a size) and from Forward Open (O->T point = output with size
  O->T - 6, T->O point = input with size T->O - 2, the configuration point).
- A replay table: every captured request that a device built from the learned identity and
  assemblies does not implement (its model answers 0x05, 0x08 or 0x14) and that got another
  reply, with that reply; matched on service, path and request data exactly.
Every value the capture does not determine gets a placeholder and is listed under `unverified`.
The model is named after the product, never after a model of the catalogue (a learned profile
does not replace a built-in model): a product named like one gets `_learned` appended.
"""

from __future__ import annotations

import struct
from pathlib import Path
from types import MappingProxyType
from typing import Any

from enip_farm.capture.exchanges import Exchange, load_exchanges
from enip_farm.config import DeviceConfig
from enip_farm.device.catalogue import Catalogue, shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.profile import resolve
from enip_farm.protocol.cip import CipDecodeError, decode_reply, decode_request, decode_unconnected_send
from enip_farm.protocol.commands import decode_identity_item, decode_send_data
from enip_farm.protocol.connection import DecodeError, decode_forward_open
from enip_farm.protocol.cpf import ItemType, decode_items
from enip_farm.protocol.encapsulation import Command
from enip_farm.protocol.epath import LogicalSegment, LogicalType, PathError, decode_epath, decode_request_path
from enip_farm.protocol.session import MessageContext

_IDENTITY_FIELDS = ("vendor_id", "device_type", "product_code", "revision", "product_name", "serial_number")
_PLACEHOLDER = MappingProxyType({"vendor_id": 0, "device_type": 0, "product_code": 0, "revision": (1, 0),
                                 "product_name": "learned"})


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
        if request[0] == 0x52 and decode_request_path(decode_request(request).path)[:2] == (6, 1):
            request = decode_unconnected_send(decode_request(request).data).message
    except (CipDecodeError, PathError, IndexError):
        pass
    return request, reply


def _identity_from_gaa(data: bytes, identity: dict[str, Any]) -> None:
    vendor, device_type, product, major, minor, _status, serial = struct.unpack_from("<HHHBBHI", data)
    name = data[15 : 15 + data[14]].decode("latin-1")
    identity.update(vendor_id=vendor, device_type=device_type, product_code=product, revision=[major, minor],
                    serial_number=serial, product_name=name)


def _identity_attribute(attribute: int, data: bytes, identity: dict[str, Any]) -> None:
    if attribute in (1, 2, 3) and len(data) >= 2:
        identity[("vendor_id", "device_type", "product_code")[attribute - 1]] = struct.unpack_from("<H", data)[0]
    elif attribute == 4 and len(data) >= 2:
        identity["revision"] = [data[0], data[1]]
    elif attribute == 6 and len(data) >= 4:
        identity["serial_number"] = struct.unpack_from("<I", data)[0]
    elif attribute == 7 and data:
        identity["product_name"] = data[1 : 1 + data[0]].decode("latin-1")


def learn(capture: str | Path, name: str | None = None, catalogue: Catalogue | None = None) -> dict[str, Any]:
    """The profile document (a one-model catalogue) learned from `capture`. `catalogue` (default:
    the shipped one) holds the names the model must not take; raises ValueError if `name` is one."""
    catalogue = shipped_catalogue() if catalogue is None else catalogue
    if name is not None and name in catalogue.models:
        raise ValueError(f"{name!r} is a model of the catalogue: a learned profile never replaces one, "
                         "choose another name")
    exchanges = [e for group in load_exchanges(capture) for e in group]
    identity: dict[str, Any] = {}
    sizes: dict[int, int] = {}
    roles: dict[str, int] = {}
    pairs: list[tuple[bytes, bytes]] = []
    for exchange in exchanges:
        if exchange.request.header.command == Command.LIST_IDENTITY and exchange.reply is not None:
            try:
                item = decode_identity_item(decode_items(exchange.reply.data)[0].data)
            except (ValueError, IndexError):
                continue
            identity.update(vendor_id=item.vendor_id, device_type=item.device_type, product_code=item.product_code,
                            revision=[item.revision_major, item.revision_minor], serial_number=item.serial_number,
                            product_name=item.product_name)
            continue
        cip = _cip_pairs(exchange)
        if cip is None:
            continue
        pairs.append(cip)
        try:
            request, reply = decode_request(cip[0]), decode_reply(cip[1])
            path = decode_request_path(request.path)
        except (CipDecodeError, PathError):
            continue
        if reply.general_status != 0:
            continue
        if path.class_id == 1 and path.instance_id == 1:
            if request.service == 0x01:
                _identity_from_gaa(reply.data, identity)
            elif request.service == 0x0E and path.attribute_id:
                _identity_attribute(path.attribute_id, reply.data, identity)
        elif path.class_id == 4 and path.instance_id and path.attribute_id == 3:
            if request.service == 0x0E:
                sizes[path.instance_id] = len(reply.data)
            elif request.service == 0x10:
                sizes[path.instance_id] = len(request.data)
                roles.setdefault("output", path.instance_id)
        elif path.class_id == 4 and path.instance_id and path.attribute_id == 4 and request.service == 0x0E:
            sizes[path.instance_id] = struct.unpack_from("<H", reply.data)[0]
        elif path.class_id == 6 and request.service in (0x54, 0x5B):
            _learn_forward_open(request.data, request.service == 0x5B, sizes, roles)

    unverified = [f"identity.{f}" for f in _IDENTITY_FIELDS if f not in identity and f != "serial_number"]
    identity = {**_PLACEHOLDER, "revision": list(_PLACEHOLDER["revision"]), **identity}
    if "input" not in roles:
        candidates = [i for i in sizes if i != roles.get("output")]
        if candidates:
            roles["input"] = candidates[0]
    assemblies = {"output": roles.get("output", 100), "input": roles.get("input", 101),
                  "configuration": roles.get("configuration", 1)}
    for role in ("output", "input", "configuration"):
        if role not in roles:
            unverified.append(f"assemblies.{role}")
    assembly_sizes = {role: sizes.get(instance, 0) for role, instance in assemblies.items()}
    for role, instance in assemblies.items():
        if instance not in sizes and role != "configuration":
            unverified.append(f"sizes.{role}")
    model_name = name or str(identity["product_name"]).replace(" ", "_") or "learned"
    while model_name in catalogue.models:
        model_name += "_learned"
    model: dict[str, Any] = {
        "kind": "base",
        "description": f"learned from {Path(capture).name}",
        "identity": identity,
        "assemblies": assemblies,
        "sizes": assembly_sizes,
        "io": {"do": 8 * assembly_sizes["output"], "di": 8 * assembly_sizes["input"]},
        "unverified": unverified,
        "replay": _replay_table(model_name, model_shell(identity, assemblies, assembly_sizes), pairs, catalogue),
    }
    return {"models": {model_name: model}}


def _learn_forward_open(data: bytes, large: bool, sizes: dict[int, int], roles: dict[str, int]) -> None:
    try:
        request = decode_forward_open(data, large)
        segments = [s for s in decode_epath(request.connection_path) if isinstance(s, LogicalSegment)]
    except (DecodeError, PathError):
        return
    points = [s.value for s in segments if s.type in (LogicalType.INSTANCE_ID, LogicalType.CONNECTION_POINT)]
    if len(points) == 3:
        roles.setdefault("configuration", points[0])
        points = points[1:]
    if len(points) == 2:
        output, inputs = points
        roles.setdefault("output", output)
        roles.setdefault("input", inputs)
        sizes.setdefault(output, max(request.o_t_parameters.size - 6, 0))
        sizes.setdefault(inputs, max(request.t_o_parameters.size - 2, 0))


def model_shell(identity: dict, assemblies: dict, sizes: dict) -> dict:
    return {"kind": "base", "description": "learning", "identity": identity, "assemblies": assemblies,
            "sizes": sizes, "io": {}}


def _replay_table(name: str, shell: dict, pairs: list[tuple[bytes, bytes]],
                  catalogue: Catalogue) -> list[dict[str, Any]]:
    """Captured requests the model would not implement, with their captured replies."""
    learning = catalogue.with_models(Catalogue.from_document({"models": {name: shell}}).models, "learning")
    device = Device(resolve(DeviceConfig(name="learning", address="127.0.0.1", model=name), learning))
    context = MessageContext("127.0.0.1", object())
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
