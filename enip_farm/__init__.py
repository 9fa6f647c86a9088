"""enip-farm: virtual EtherNet/IP I/O devices for testing robot controller software."""

__version__ = "0.1.0"
