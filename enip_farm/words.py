"""The words the farm prints about counts (`1 device`, `8 devices`), and the names it makes of a
product's name (`model_name`)."""

from __future__ import annotations

import re


def plural(count: int, noun: str, nouns: str | None = None) -> str:
    """The count and the noun it takes: `plural(1, "device")` is `1 device`, `plural(0, "entry", "entries")`
    is `0 entries`."""
    return f"{count} {noun if count == 1 else nouns or noun + 's'}"


def model_name(product_name: str) -> str:
    """A model's name made of a product's whole name, as `eds import` and `learn` name what they
    read: letters, digits, - and _ (a file name, a URL's segment, the MODEL.field of `unverified`):
    `ABB EtherNet/IP Anybus Adapter Device` is `ABB_EtherNet_IP_Anybus_Adapter_Device`."""
    return re.sub(r"[^\w-]+", "_", product_name).strip("_")
