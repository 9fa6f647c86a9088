"""The cyclic I/O thread's real-time scheduling (server/realtime.py, `cyclic_io.realtime_priority`)."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import pytest

from enip_farm.config import ConfigError, load_config
from enip_farm.farm.farm import Farm
from enip_farm.pytest_plugin import AddressPool
from enip_farm.server import realtime


def _farm(tmp_path: Path, address: str, priority: int) -> Farm:
    path = tmp_path / "cell.yaml"
    path.write_text(f"devices:\n  - {{name: a, address: {address}, model: DSQC1030}}\ndiscovery: false\n"
                    f"cyclic_io: {{realtime_priority: {priority}, budget_datagrams_per_s: 1000}}\n")
    return Farm(load_config(path))


@pytest.mark.integration
@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_the_cyclic_io_thread_runs_sched_fifo_at_the_priority_asked(free_address: AddressPool,
                                                                     tmp_path: Path) -> None:
    farm = _farm(tmp_path, free_address(), 7)
    with farm.running_in_thread():
        thread = farm._implicit.thread  # type: ignore[union-attr]
        tid = thread.native_id
        assert tid is not None and tid != os.getpid()
        assert os.sched_getscheduler(tid) == os.SCHED_FIFO
        assert os.sched_getparam(tid).sched_priority == 7
        assert os.sched_getscheduler(0) == os.SCHED_OTHER  # only that thread: the event loop's is as it was


@pytest.mark.integration
def test_the_cyclic_io_thread_keeps_the_normal_policy_by_default(free_address: AddressPool, tmp_path: Path) -> None:
    farm = _farm(tmp_path, free_address(), 0)
    with farm.running_in_thread():
        assert os.sched_getscheduler(farm._implicit.thread.native_id) == os.SCHED_OTHER  # type: ignore[union-attr]


@pytest.mark.integration
def test_without_the_privilege_the_thread_says_why_and_runs_all_the_same(
        free_address: AddressPool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    def refused(pid: int, policy: int, param: os.sched_param) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refused)
    assert realtime.run_realtime(0) is None  # not asked: nothing tried
    farm = _farm(tmp_path, free_address(), 5)
    with caplog.at_level(logging.WARNING, logger="enip_farm.server.implicit"), farm.running_in_thread():
        thread = farm._implicit.thread  # type: ignore[union-attr]
        deadline = time.monotonic() + 10
        while not thread.running(time.monotonic_ns()) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert thread.running(time.monotonic_ns())
        assert os.sched_getscheduler(thread.native_id) == os.SCHED_OTHER
    assert [r.getMessage() for r in caplog.records if r.name == "enip_farm.server.implicit"] == [
        "cannot run the cyclic I/O thread SCHED_FIFO at priority 5: [Errno 1] Operation not permitted; "
        "it runs at the normal policy"]


def test_a_priority_past_sched_fifos_range_is_a_configuration_error(tmp_path: Path) -> None:
    path = tmp_path / "cell.yaml"
    path.write_text("devices:\n  - {name: a, address: 127.0.0.1, model: DSQC1030}\n"
                    "cyclic_io: {realtime_priority: 100}\n")
    with pytest.raises(ConfigError, match="realtime_priority"):
        load_config(path)
