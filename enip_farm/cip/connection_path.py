"""The connection path of a Forward Open (CIP Networks Library Vol. 1, 3-5.4.1.10 and appendix C):
the route to this device, the electronic key held against the device's identity (C-1.4.2), the
points of an assembly's application path (configuration instance, consumed and produced
connection points) and the data segments. Pure functions: the admissions (cip/admission.py,
cip/safety/admission.py) turn what they find into refusals.
"""

from __future__ import annotations

from typing import NamedTuple

from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.epath import (
    DataSegment,
    ElectronicKey,
    LogicalSegment,
    LogicalType,
    PathError,
    PortSegment,
    decode_epath,
)
from enip_farm.protocol.status import ExtendedStatus as X

#: A route to this device itself: backplane port 1, slot 0.
SELF = PortSegment(1, b"\x00")
_ASSEMBLY = LogicalSegment(LogicalType.CLASS_ID, ClassCode.ASSEMBLY)


class KeyIdentity(NamedTuple):
    """The identity an electronic key is checked against (Vol. 1, C-1.4.2)."""

    vendor_id: int
    device_type: int
    product_code: int
    revision: tuple[int, int]


def key_mismatch(key: ElectronicKey, identity: KeyIdentity) -> int | None:
    """The extended status of a key the device does not match, None if it matches (zeros match anything)."""
    if ((key.vendor_id and key.vendor_id != identity.vendor_id)
            or (key.product_code and key.product_code != identity.product_code)):
        return X.VENDOR_OR_PRODUCT_MISMATCH
    if key.device_type and key.device_type != identity.device_type:
        return X.DEVICE_TYPE_MISMATCH
    major, minor = identity.revision
    if key.major_revision:
        if key.compatibility:  # any revision that can emulate the requested one
            if key.major_revision != major or (key.minor_revision and key.minor_revision > minor):
                return X.REVISION_MISMATCH
        elif key.major_revision != major or (key.minor_revision and key.minor_revision != minor):
            return X.REVISION_MISMATCH
    return None


def strip_route(segments: list) -> int:
    """Take the route to this device off the front of `segments`; the bytes it took."""
    size = 0
    while segments and segments[0] == SELF:
        segments.pop(0)
        size += 2
    return size


def routed_segments(connection_path: bytes) -> list | None:
    """The path's segments after the route to this device; None for a path that cannot be read."""
    try:
        segments = decode_epath(connection_path)
    except PathError:
        return None
    strip_route(segments)
    return segments


def electronic_key(connection_path: bytes) -> ElectronicKey | None:
    """The path's electronic key (first after the route to this device); None without one."""
    segments = routed_segments(connection_path)
    return segments[0] if segments and isinstance(segments[0], ElectronicKey) else None


def application_segments(connection_path: bytes, identity: KeyIdentity) -> list | int:
    """The path's segments after the route to this device and the electronic key; or the extended
    status of a path that cannot be read (0x0315) or of a key the device does not match."""
    segments = routed_segments(connection_path)
    if segments is None:
        return X.INVALID_SEGMENT
    if segments and isinstance(segments[0], ElectronicKey):
        mismatch = key_mismatch(segments.pop(0), identity)
        if mismatch is not None:
            return mismatch
    return segments


def assembly_points(segments: list) -> tuple[int | None, int, int] | None:
    """(configuration, consumed O->T, produced T->O) points of an assembly's application path, the
    configuration None where the path gives two; None if the path is no such thing."""
    if not segments or segments[0] != _ASSEMBLY:
        return None
    values = []
    for segment in segments[1:]:
        if not isinstance(segment, LogicalSegment) or segment.type not in (
                LogicalType.INSTANCE_ID, LogicalType.CONNECTION_POINT):
            return None
        values.append(segment.value)
    if len(values) == 3:
        return values[0], values[1], values[2]
    if len(values) == 2:
        return None, values[0], values[1]
    return None


def data_segments(connection_path: bytes) -> list[bytes]:
    """The data of the path's data segments (a configuration's data); none in a path that cannot be read."""
    try:
        return [s.data for s in decode_epath(connection_path) if isinstance(s, DataSegment)]
    except PathError:
        return []
