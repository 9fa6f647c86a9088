"""Issue 31's shape counts, for a closing note: in TREE/enip_farm, the string literals that are an
event's wire kind (tokens equal to a kind, so docstrings and comments do not count), outside the
modules that define the wire's words; the `.startswith(` on an event's detail; and the places
outside device/guard.py that take a device's lock or publish and snapshot around it.

    python bench/event_kinds.py [TREE]    # default: this checkout
"""

from __future__ import annotations

import ast
import io
import re
import sys
import tokenize
from pathlib import Path

KINDS = frozenset({
    "image changed", "request", "connection opened", "connection closed", "connection timed out",
    "connection refused", "connection faulted", "connection short data", "safe state", "safety crc fault",
    "safety timing fault", "fault injected", "fault cleared", "reset", "reset done", "wired", "tcp connected",
    "tcp closed", "tcp inactive", "encapsulation refused", "encapsulation ignored", "session registered",
    "session ended", "power lost", "power returned", "address conflict", "link down", "link up",
    "address still taken", "scenario step", "self test done"})
DEFINING = frozenset({"enip_farm/device/events.py", "enip_farm/cip/connection_events.py"})
LOCK = re.compile(r"with [A-Za-z_.]*\.lock\b|\.lock\.acquire|\.locked\(|guard\.(publish|snapshot)\(")


def main() -> None:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else ".")
    literals, startswith, locks = [], [], []
    for path in sorted((root / "enip_farm").rglob("*.py")):
        name = str(path.relative_to(root))
        text = path.read_text()
        for token in tokenize.generate_tokens(io.StringIO(text).readline):
            if token.type == tokenize.STRING and name not in DEFINING:
                try:
                    value = ast.literal_eval(token.string)
                except (ValueError, SyntaxError):
                    continue
                if value in KINDS:
                    literals.append(f"{name}:{token.start[0]} {value!r}")
        for number, line in enumerate(text.splitlines(), 1):
            if ".startswith(" in line and ("detail" in line or "event" in line):
                startswith.append(f"{name}:{number}")
            if name != "enip_farm/device/guard.py" and LOCK.search(line) and "_lock" not in line:
                locks.append(f"{name}:{number}")
    for title, found in (("event-kind literals outside the defining modules", literals),
                         (".startswith( on an event's detail", startswith),
                         ("device-lock or publish/snapshot sites outside device/guard.py", locks)):
        print(f"{title}: {len(found)}")
        for where in found:
            print(f"  {where}")


if __name__ == "__main__":
    main()
