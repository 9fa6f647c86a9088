"""CIP general status codes (CIP Networks Library Vol. 1, appendix B-1) and connection-manager
extended status codes (Vol. 1, table 3-5.33)."""

from enum import IntEnum


class GeneralStatus(IntEnum):
    SUCCESS = 0x00
    CONNECTION_FAILURE = 0x01
    PATH_SEGMENT_ERROR = 0x04
    PATH_DESTINATION_UNKNOWN = 0x05
    SERVICE_NOT_SUPPORTED = 0x08
    INVALID_ATTRIBUTE_VALUE = 0x09
    OBJECT_STATE_CONFLICT = 0x0C
    ATTRIBUTE_NOT_SETTABLE = 0x0E
    DEVICE_STATE_CONFLICT = 0x10
    NOT_ENOUGH_DATA = 0x13
    ATTRIBUTE_NOT_SUPPORTED = 0x14
    TOO_MUCH_DATA = 0x15
    OBJECT_DOES_NOT_EXIST = 0x16
    EMBEDDED_SERVICE_ERROR = 0x1E
    VENDOR_SPECIFIC = 0x1F
    INVALID_PARAMETER = 0x20
    PATH_SIZE_INVALID = 0x26


class ExtendedStatus(IntEnum):
    """Extended status words that follow general status 0x01."""

    INVALID_PORT = 0x0311
    INVALID_LINK_ADDRESS = 0x0312
