"""Issue 28, item 2: CIP Safety faults of the DSQC1042 (device/safety_faults.py) as a real safety
originator sees them: cm-ethernetip (PyPI), run from its own venv (tests/cm_ethernetip). It checks
every safe-input message's CRCs (a wrong one is its `RX CRC FAIL`), takes each message's data and
answers the target's pings; it does not supervise time stamps' age or its own pings, so for those
two the test shows what reaches it: data that stands still, and no time coordination (so it never
leaves idle)."""

from __future__ import annotations

import time

import pytest

from tests.helpers import wait_for
from tests.test_cm_ethernetip import cm_python, originator, safety_args  # noqa: F401 (fixtures)

pytestmark = pytest.mark.system


def _stats(scanner) -> dict:
    scanner.send(cmd="stats")
    return scanner.wait("stats")


def test_wrong_crcs_are_what_the_originator_counts_and_drops(enip_farm, originator) -> None:  # noqa: F811
    farm = enip_farm(name="s1", model="DSQC1042")
    scanner = originator(**safety_args(farm))
    assert scanner.wait("open")["event"] == "open"
    farm["s1"].set(DI3=1)
    assert scanner.wait("rx", data="0400")["data"] == "0400"
    assert _stats(scanner)["crc_faults"] == 0
    farm.inject("s1", "safety-crc")
    farm["s1"].set(DI12=1)
    # waits for the state, not a guessed time (a starved originator reads its datagrams late)
    assert wait_for(lambda: _stats(scanner)["crc_faults"] >= 10, timeout=30)  # every message since, each refused
    stats = _stats(scanner)
    assert all(event.get("data") != "0408" for event in scanner.seen if event["event"] == "rx")
    assert farm.device("s1").faults.safety_tamper.tampered >= stats["crc_faults"]
    farm.clear("s1")
    assert scanner.wait("rx", data="0408")["data"] == "0408"  # valid again: the new data taken


def test_stale_messages_stand_still_for_the_originator(enip_farm, originator) -> None:  # noqa: F811
    farm = enip_farm(name="s1", model="DSQC1042")
    scanner = originator(**safety_args(farm))
    assert scanner.wait("open")["event"] == "open"
    farm["s1"].set(DI3=1)
    assert scanner.wait("rx", data="0400")["data"] == "0400"
    farm.inject("s1", "safety-stale")
    tamper = farm.device("s1").faults.safety_tamper
    assert wait_for(lambda: tamper.kept)  # the message that will stand still, taken before the input changes
    before = _stats(scanner)["rx"]
    farm["s1"].set(DI12=1)  # in the input image when set() returns: every message produced since carries it
    replaced = tamper.tampered
    # waits for the states, not a guessed time (a starved originator reads its datagrams late): ten
    # messages with the new input sent as the kept one, and ten more taken by the originator
    assert wait_for(lambda: tamper.tampered - replaced >= 10, timeout=30)
    assert wait_for(lambda: _stats(scanner)["rx"] - before >= 10, timeout=30)
    assert _stats(scanner)["crc_faults"] == 0  # messages come, their CRCs valid
    assert all(event.get("data") != "0408" for event in scanner.seen if event["event"] == "rx")  # the same one
    farm.clear("s1")
    assert scanner.wait("rx", data="0408")["data"] == "0408"


def test_without_time_coordination_the_originator_never_runs_its_safe_outputs(enip_farm, originator) -> None:  # noqa: F811
    farm = enip_farm(name="s1", model="DSQC1042")
    farm.inject("s1", "safety-time-coordination")
    scanner = originator(**safety_args(farm))
    assert scanner.wait("open")["event"] == "open"
    scanner.send(cmd="out", data="05")
    time.sleep(0.5)
    assert farm["s1"].get("DO1-4") == [0, 0, 0, 0]  # idle: no answer to its first ping, no run
    assert farm.device("s1").faults.safety_tamper.tampered >= 1
    servers = [c for c in farm.device("s1").connections.values() if c.kind.value == "safety output (server)"]
    assert len(servers) == 1 and not servers[0].run  # the originator's messages all idle
