"""Attributes as an object declares them (CIP Networks Library Vol. 1, 4-4 and appendix A; the
shape of OpENer's `InsertAttribute(instance, number, type, encoder, decoder, &data, access)`): one
line per attribute gives its id, its data type, where its value comes from and its access. The type
gives the encoding, the size and how a value is read from request data; the access says which
common services answer it:

- `Access.GET`: Get_Attribute_Single and Get_Attribute_List return it; without it they answer 0x14.
- `Access.SET`: Set_Attribute_Single and Set_Attribute_List write it: request data shorter than the
  type says is 0x13, longer 0x15, then the setter takes the decoded value and answers a status
  (0x09 for a value out of range, ...). A gettable attribute without it is 0x0E (not settable).
- `Access.ALL`: Get_Attributes_All returns it, in id order. An attribute with ALL only is an
  optional attribute the instance does not implement: the single and list services answer 0x14
  and Get_Attributes_All carries its value (the spec's default) in its place.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from enum import Flag
from typing import Any

from enip_farm.cip.data_types import CipType
from enip_farm.protocol.status import GeneralStatus


class Access(Flag):
    NONE = 0
    GET = 1
    SET = 2
    ALL = 4


GET_ALL = Access.GET | Access.ALL  # OpENer's kGetableSingleAndAll, the usual access
GET_SET_ALL = Access.GET | Access.SET | Access.ALL


class Attribute:
    """One attribute: `value` (a constant, encoded once) or `get` (called at each read) gives its
    value, `set` (the decoded value in, a general status out) takes a new one, `guard` (when
    given) answers a status before the value is read: a state in which the attribute cannot be set."""

    __slots__ = ("id", "type", "access", "get", "set", "guard", "encoded", "gettable", "served", "in_all")

    def __init__(self, id: int, type: CipType, get: Callable[[], Any] | None = None,
                 set: Callable[[Any], int] | None = None, *, value: Any = None, access: Access | None = None,
                 guard: Callable[[], int] | None = None) -> None:
        if (get is None) == (value is None):
            raise ValueError(f"attribute {id}: a getter or a constant value, one of them")
        if access is None:
            access = GET_SET_ALL if set is not None else GET_ALL
        if (Access.SET in access) != (set is not None):
            raise ValueError(f"attribute {id}: settable if and only if it has a setter")
        self.id, self.type, self.access, self.get, self.set, self.guard = id, type, access, get, set, guard
        self.encoded = type.encode(value) if value is not None else None
        # the access as plain truths, for the request path (a Flag operation costs microseconds)
        self.gettable = Access.GET in access
        self.served = self.gettable or set is not None  # known to the single and list services, else 0x14
        self.in_all = Access.ALL in access

    def read(self) -> bytes:
        encoded = self.encoded
        return encoded if encoded is not None else self.type.encode(self.get())  # type: ignore[misc]

    def write(self, data: bytes) -> int:
        """Set_Attribute_Single/List on it: the general status."""
        if self.set is None:
            return GeneralStatus.ATTRIBUTE_NOT_SETTABLE if self.served else GeneralStatus.ATTRIBUTE_NOT_SUPPORTED
        if self.guard is not None:
            status = self.guard()
            if status:
                return status
        size = self.type.size_in(data)
        if size is None or size > len(data):
            return GeneralStatus.NOT_ENOUGH_DATA
        if size < len(data):
            return GeneralStatus.TOO_MUCH_DATA
        return self.set(self.type.decode(data))

    def __repr__(self) -> str:
        return f"Attribute({self.id}, {self.type!r}, {self.access})"


class CipInstance:
    """An instance (or the class itself, as instance 0): its attributes by id, and the members of
    Get_Attributes_All in id order."""

    __slots__ = ("attributes", "all_members")

    def __init__(self, attributes: Iterable[Attribute] = ()) -> None:
        self.attributes: dict[int, Attribute] = {}
        self.declare(*attributes)

    def declare(self, *attributes: Attribute) -> None:
        """Add (or replace) attributes."""
        merged = {**self.attributes, **{a.id: a for a in attributes}}
        self.attributes = dict(sorted(merged.items()))
        self.all_members = tuple(a for a in self.attributes.values() if a.in_all)

    def served(self, attribute_id: int | None) -> Attribute | None:
        """The attribute the single and list services answer for this id, if any."""
        attribute = self.attributes.get(attribute_id)  # type: ignore[arg-type]
        return attribute if attribute is not None and attribute.served else None

    def served_ids(self) -> list[int]:
        return [i for i, a in self.attributes.items() if a.served]

    def get_attributes_all(self) -> bytes:
        return b"".join(a.read() for a in self.all_members)
