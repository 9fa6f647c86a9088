"""cm-ethernetip (PyPI, Apache-2.0) as a real originator: its own venv (its top-level package
`ethernetip` clashes with the `ethernetip` scanner of the test dependencies) and a driver script
(`originator.py`) run by that venv's python."""

from __future__ import annotations

import ipaddress
import json
import os
import subprocess
import sys
from pathlib import Path

from tests.helpers import read_lines

DRIVER = Path(__file__).with_name("originator.py")
TARGET = Path(__file__).with_name("target.py")
VERSION = "0.1.0"  # the workarounds in originator.py are for this version's quirks


def make_venv(root: Path) -> Path:
    """A venv at `root` with cm-ethernetip from PyPI (no system site packages); its python.
    Raises subprocess.CalledProcessError when pip cannot install it."""
    python = root / "bin" / "python"
    if not python.exists():
        subprocess.run([sys.executable, "-m", "venv", str(root)], check=True, capture_output=True, timeout=300)
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                    f"cm-ethernetip=={VERSION}"], check=True, capture_output=True, timeout=600)
    return python


def node_address(address: str) -> int:
    """The TUNID node address of a farm device: its IPv4 address as a UDINT."""
    return int(ipaddress.IPv4Address(address))


class CmOriginator:
    """The driver script running; one JSON object per line each way."""

    def __init__(self, python: Path, args: dict) -> None:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # the venv's packages only
        self.process = subprocess.Popen([str(python), str(DRIVER), json.dumps(args)], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        self.seen: list[dict] = []

    def send(self, **command: object) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write(json.dumps(command) + "\n")
        self.process.stdin.flush()

    def wait(self, event: str, timeout: float = 20.0, **fields: object) -> dict:
        """The next event named `event` (with these field values); TimeoutError if none comes."""
        assert self.process.stdout is not None
        while True:
            lines = read_lines(self.process.stdout, 1, timeout)
            if not lines:
                raise AssertionError(f"the originator exited: {self.process.stderr.read()}")  # type: ignore[union-attr]
            message = json.loads(lines[0])
            self.seen.append(message)
            if message["event"] == event and all(message.get(k) == v for k, v in fields.items()):
                return message
            if message["event"] == "error":
                return message

    def close(self) -> None:
        if self.process.poll() is None:
            try:
                self.send(cmd="close")
                self.process.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                self.process.kill()
                self.process.wait(10)
        for stream in (self.process.stdin, self.process.stdout, self.process.stderr):
            if stream is not None:
                stream.close()


class CmTarget:
    """cm-ethernetip's own safety target (target.py) listening on `address`, until closed."""

    def __init__(self, python: Path, address: str, snn: str) -> None:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        self.process = subprocess.Popen([str(python), str(TARGET), json.dumps({"address": address, "snn": snn})],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, env=env)
        assert self.process.stdout is not None
        lines = read_lines(self.process.stdout, 1, 30.0)
        if not lines or json.loads(lines[0]).get("event") != "ready":
            self.close()
            raise AssertionError(f"cm-ethernetip's target did not start: {lines}")

    def close(self) -> None:
        if self.process.stdin is not None and not self.process.stdin.closed:
            self.process.stdin.close()
        try:
            self.process.wait(10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(10)
        for stream in (self.process.stdout, self.process.stderr):
            if stream is not None:
                stream.close()
