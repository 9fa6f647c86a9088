"""enip-farm: virtual EtherNet/IP I/O devices for testing robot controller software.

The public Python API, importable from here (`from enip_farm import Farm`):

- `Farm(config, http=None, ...)`: a cell served in this process; an async context manager, or
  `with farm.running_in_thread():` for synchronous callers; `farm["io1"]` is a `DeviceHandle`.
- `FarmConfig`, `load_config(path)`, `parse_config(dict)`: a cell's configuration, checked
  (`load_config` in one pass with building its devices: every problem of the file at once);
  `ConfigError` (one line per problem) when it is not servable.
- `BindError`: a device's address or port cannot be bound (the message says what to do).
- `EioImportWarning`: what importing a controller's EIO.cfg did not import (the pytest fixture).

Each name is imported on first use (a module `__getattr__`, PEP 562), so that `import
enip_farm.protocol.cip` and the command line do not pay for the farm's imports.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

__version__ = "0.1.0"

#: Each public name and the module that defines it.
_PUBLIC = {
    "Farm": "enip_farm.farm.farm",
    "BindError": "enip_farm.farm.farm",
    "DeviceHandle": "enip_farm.control.handle",
    "FarmConfig": "enip_farm.config",
    "ConfigError": "enip_farm.config",
    "load_config": "enip_farm.farm.cell",
    "parse_config": "enip_farm.config",
    "EioImportWarning": "enip_farm.eio.importer",
}

__all__ = ["BindError", "ConfigError", "DeviceHandle", "EioImportWarning", "Farm", "FarmConfig", "__version__",
           "load_config", "parse_config"]

def __getattr__(name: str) -> Any:
    if name not in _PUBLIC:
        raise AttributeError(f"module 'enip_farm' has no attribute {name!r}")
    value = getattr(import_module(_PUBLIC[name]), name)
    globals()[name] = value  # once imported, an ordinary attribute
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_PUBLIC])
