"""CIP general status codes (CIP Networks Library Vol. 1, appendix B-1) and connection-manager
extended status codes (Vol. 1, table 3-5.33)."""

from collections.abc import Mapping
from enum import IntEnum
from types import MappingProxyType


class GeneralStatus(IntEnum):
    SUCCESS = 0x00
    CONNECTION_FAILURE = 0x01
    RESOURCE_UNAVAILABLE = 0x02
    PATH_SEGMENT_ERROR = 0x04
    PATH_DESTINATION_UNKNOWN = 0x05
    PARTIAL_TRANSFER = 0x06
    SERVICE_NOT_SUPPORTED = 0x08
    INVALID_ATTRIBUTE_VALUE = 0x09
    ATTRIBUTE_LIST_ERROR = 0x0A
    OBJECT_STATE_CONFLICT = 0x0C
    ATTRIBUTE_NOT_SETTABLE = 0x0E
    PRIVILEGE_VIOLATION = 0x0F
    DEVICE_STATE_CONFLICT = 0x10
    NOT_ENOUGH_DATA = 0x13
    ATTRIBUTE_NOT_SUPPORTED = 0x14
    TOO_MUCH_DATA = 0x15
    OBJECT_DOES_NOT_EXIST = 0x16
    EMBEDDED_SERVICE_ERROR = 0x1E
    VENDOR_SPECIFIC = 0x1F
    INVALID_PARAMETER = 0x20
    PATH_SIZE_INVALID = 0x26
    SERVICE_NOT_SUPPORTED_FOR_PATH = 0x2E


class ExtendedStatus(IntEnum):
    """Extended status words that follow general status 0x01."""

    CONNECTION_IN_USE = 0x0100
    TRANSPORT_TRIGGER_NOT_SUPPORTED = 0x0103
    CONFIGURATION_OWNED = 0x0105  # configuration already owned by another originator
    OWNERSHIP_CONFLICT = 0x0106
    CONNECTION_NOT_FOUND = 0x0107
    INVALID_CONNECTION_TYPE = 0x0108
    RPI_NOT_SUPPORTED = 0x0111
    RPI_NOT_ACCEPTABLE = 0x0112  # followed by the acceptable RPI types and the O->T, T->O RPIs
    OUT_OF_CONNECTIONS = 0x0113
    VENDOR_OR_PRODUCT_MISMATCH = 0x0114
    DEVICE_TYPE_MISMATCH = 0x0115
    REVISION_MISMATCH = 0x0116
    NON_LISTEN_ONLY_NOT_OPENED = 0x0119
    INVALID_O_T_SIZE = 0x0127
    INVALID_T_O_SIZE = 0x0128
    INVALID_CONFIGURATION_PATH = 0x0129
    INVALID_CONSUMING_PATH = 0x012A
    INVALID_PRODUCING_PATH = 0x012B
    NULL_FORWARD_OPEN_NOT_SUPPORTED = 0x0132
    CONNECTION_TIMED_OUT = 0x0203
    PARAMETER_ERROR = 0x0205  # parameter error in unconnected request service (Vol. 1); the farm's
    # choice for a SafetyOpen whose server initial timestamp / rollover is not "not used", and for a
    # Forward Open whose timeout multiplier is reserved (8-255)
    INVALID_PORT = 0x0311
    INVALID_LINK_ADDRESS = 0x0312
    INVALID_SEGMENT = 0x0315
    MISCELLANEOUS = 0x031C  # no other extended status applies; the farm's choice for a SafetyOpen's
    # time correction EPI and max fault number
    # CIP Safety (Vol. 5, table 3-5.33 extended): refusals of a SafetyOpen
    INVALID_SAFETY_CONNECTION_SIZE = 0x0802
    INVALID_SAFETY_FORMAT = 0x0803
    INVALID_TIME_CORRECTION_PARAMETERS = 0x0804
    INVALID_PING_INTERVAL_EPI_MULTIPLIER = 0x0805
    INVALID_TIME_COORD_MSG_MIN_MULTIPLIER = 0x0806
    INVALID_NETWORK_TIME_EXPECTATION_MULTIPLIER = 0x0807
    INVALID_SAFETY_TIMEOUT_MULTIPLIER = 0x0808
    INVALID_MAX_CONSUMER_NUMBER = 0x0809
    INVALID_CPCRC = 0x080A
    INVALID_TIME_CORRECTION_CONNECTION_ID = 0x080B
    SCID_MISMATCH = 0x080C
    TUNID_NOT_SET = 0x080D
    TUNID_MISMATCH = 0x080E
    CONFIGURATION_OPERATION_NOT_ALLOWED = 0x080F
    MULTICAST_PING_INTERVAL_EPI_MULTIPLIER = 0x0815  # a multicast join: not the producer's
    MULTICAST_MAX_CONSUMER_NUMBER = 0x0816
    MULTICAST_SAFETY_FORMAT = 0x0817


#: General status in words (Vol. 1, appendix B-1), for logs and messages.
GENERAL_STATUS_TEXT: Mapping[int, str] = MappingProxyType({
    0x00: "success",
    0x01: "connection failure",
    0x02: "resource unavailable",
    0x03: "invalid parameter value",
    0x04: "path segment error",
    0x05: "path destination unknown",
    0x06: "partial transfer",
    0x07: "connection lost",
    0x08: "service not supported",
    0x09: "invalid attribute value",
    0x0A: "attribute list error",
    0x0B: "already in requested mode/state",
    0x0C: "object state conflict",
    0x0D: "object already exists",
    0x0E: "attribute not settable",
    0x0F: "privilege violation",
    0x10: "device state conflict",
    0x11: "reply data too large",
    0x12: "fragmentation of a primitive value",
    0x13: "not enough data",
    0x14: "attribute not supported",
    0x15: "too much data",
    0x16: "object does not exist",
    0x17: "service fragmentation sequence not in progress",
    0x18: "no stored attribute data",
    0x19: "store operation failure",
    0x1A: "routing failure, request packet too large",
    0x1B: "routing failure, response packet too large",
    0x1C: "missing attribute list entry data",
    0x1D: "invalid attribute value list",
    0x1E: "embedded service error",
    0x1F: "vendor specific error",
    0x20: "invalid parameter",
    0x21: "write-once value or medium already written",
    0x22: "invalid reply received",
    0x25: "key failure in path",
    0x26: "path size invalid",
    0x27: "unexpected attribute in list",
    0x28: "invalid member id",
    0x29: "member not settable",
})

#: Connection Manager extended status in words (Vol. 1, table 3-5.33).
EXTENDED_STATUS_TEXT: Mapping[int, str] = MappingProxyType({
    0x0100: "connection in use or duplicate Forward Open",
    0x0103: "transport class and trigger combination not supported",
    0x0106: "ownership conflict",
    0x0107: "target connection not found",
    0x0108: "invalid network connection parameter",
    0x0109: "invalid connection size",
    0x0110: "target for connection not configured",
    0x0111: "RPI not supported",
    0x0112: "RPI values not acceptable",
    0x0113: "out of connections",
    0x0114: "vendor id or product code mismatch",
    0x0115: "device type mismatch",
    0x0116: "revision mismatch",
    0x0119: "non-listen-only connection not opened",
    0x0127: "invalid O->T connection size",
    0x0128: "invalid T->O connection size",
    0x0129: "invalid configuration application path",
    0x012A: "invalid consuming application path",
    0x012B: "invalid producing application path",
    0x0132: "null Forward Open not supported",
    0x0203: "connection timed out",
    0x0205: "parameter error in unconnected request service",
    0x0311: "invalid port in the route path",
    0x0312: "invalid link address in the route path",
    0x0315: "invalid segment in the connection path",
    0x031C: "miscellaneous",
    0x0802: "invalid safety connection size",
    0x0803: "invalid safety connection format",
    0x0804: "invalid time correction connection parameters",
    0x0805: "invalid ping interval EPI multiplier",
    0x0806: "invalid time coordination message min multiplier",
    0x0807: "invalid network time expectation multiplier",
    0x0808: "invalid timeout multiplier",
    0x0809: "invalid max consumer number",
    0x080A: "invalid CPCRC",
    0x080B: "time correction connection id invalid",
    0x080C: "SCID mismatch",
    0x080D: "TUNID not set",
    0x080E: "TUNID mismatch",
    0x0815: "invalid ping interval EPI multiplier on multicast join",
    0x0816: "invalid max consumer number on multicast join",
    0x0817: "invalid safety network segment format on multicast join",
})


def describe_status(general: int, extended: int | None = None) -> str:
    """A CIP status in hex and words, e.g. `0x01/0x0111 connection failure: RPI not supported`."""
    words = GENERAL_STATUS_TEXT.get(general, "unknown status")
    if extended is None:
        return f"0x{general:02X} {words}"
    return f"0x{general:02X}/0x{extended:04X} {words}: {EXTENDED_STATUS_TEXT.get(extended, 'unknown extended status')}"
