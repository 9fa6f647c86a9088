"""The cyclic I/O budget (cip/budget.py), its admission in the connection table (0x01/0x0113 past
it, the figures in the refusal, released on every kind of close), the lag watch of the I/O thread,
and the budget measured at start. Unit tests with an injected clock, then one farm on loopback."""

from __future__ import annotations

import random
from pathlib import Path

import httpx
import pytest

from enip_farm.cip.admission import Originator
from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.budget import CALM_SECONDS, LAG_LIMIT_NS, MIN_DATAGRAMS, CyclicBudget
from enip_farm.cip.connection_events import ConnectionRefused
from enip_farm.cip.connection_path import KeyIdentity
from enip_farm.cip.connection_policy import ConnectionPolicy, Refusal
from enip_farm.cip.connection_table import ConnectionTable, Opened
from enip_farm.config import BUDGET_UTILISATION as UTILISATION
from enip_farm.config import CyclicIoConfig
from enip_farm.server.calibrate import measure_budget
from enip_farm.server.implicit import OVERLOAD_LAG_NS, Lag
from enip_farm.server.running_budget import RunningBudget
from tests.fuzzing import dsqc1030_profile
from tests.helpers import RawClient, metric_samples
from tests.test_connection_table import INPUT_ONLY_PATH, LISTEN_ONLY_PATH, MULTICAST, T0, request
from tests.test_implicit import forward_close, forward_open

pytestmark = pytest.mark.class1_paths  # both class-1 paths (tests/conftest.py)

ROOT = Path(__file__).resolve().parent.parent

MS = 1_000_000
ORIGINATOR = Originator("127.0.0.9")


def table_with(budget: CyclicBudget) -> ConnectionTable:
    assemblies = {"output": AssemblyInstance(100, 2, True), "input": AssemblyInstance(101, 2, False),
                  "configuration": AssemblyInstance(1, 0, True)}
    policy = ConnectionPolicy(
        rpi_min_us=2_000, rpi_max_us=10_000_000, max_class1_connections=8, max_class3_connections=6,
        outputs_off_on_idle=True, outputs_off_on_fault=True, first_watchdog_ns=0,
        input_only_point=198, listen_only_point=199, multicast_group="239.192.1.0")
    return ConnectionTable(assemblies, policy, lambda: KeyIdentity(75, 7, 1030, (1, 1)), rng=random.Random(1),
                           budget=budget)


@pytest.mark.parametrize(("o_t", "t_o", "rate"), [(10_000, 10_000, 200.0), (2_000, 10_000, 600.0),
                                                   (10_000, None, 100.0), (1_000_000, 1_000_000, 2.0)])
def test_a_connection_needs_its_o_t_and_the_t_o_it_starts(o_t: int, t_o: int | None, rate: float) -> None:
    assert CyclicBudget.rate(o_t, t_o) == rate


def test_past_the_budget_a_forward_open_is_refused_0x0113_with_the_figures() -> None:
    budget = CyclicBudget(450)
    first, second = table_with(budget), table_with(budget)  # two devices of one I/O thread share it
    opened = first.forward_open(request(rpi_us=10_000), ORIGINATOR, T0)
    assert type(opened) is Opened and budget.reserved == 200
    assert type(second.forward_open(request(rpi_us=10_000), ORIGINATOR, T0)) is Opened
    assert budget.reserved == 400
    third = table_with(budget)
    refused = third.forward_open(request(rpi_us=10_000, o_t_size=8), ORIGINATOR, T0)
    assert refused == Refusal(0x0113)
    assert budget.reserved == 400 and budget.refused == 1 and not third.connections
    (event,) = [e for e in third.pop_events() if type(e) is ConnectionRefused]
    assert event.reason.endswith("0x01/0x0113 connection failure: out of connections (class 1, O->T RPI 10000 us "
                                 "8 bytes, T->O RPI 10000 us 4 bytes, path 20 04 24 01 2c 64 2c 65): the farm's "
                                 "cyclic I/O budget is 450 datagrams/s per worker, 400 taken, this connection "
                                 "needs 200")
    # a connection that needs less still fits: 25 + 25 at RPI 80 ms
    assert type(third.forward_open(request(rpi_us=80_000), ORIGINATOR, T0)) is Opened
    assert budget.reserved == 425


def test_every_close_gives_the_budget_back() -> None:
    budget = CyclicBudget(1_000)
    table = table_with(budget)
    closed = table.forward_open(request(rpi_us=10_000), ORIGINATOR, T0)
    timed_out = table.forward_open(request(path=INPUT_ONLY_PATH, o_t_size=2, rpi_us=20_000, multiplier=0),
                                   Originator("127.0.0.10"), T0)
    assert budget.reserved == 300
    table.forward_close(closed.connection.triad, T0 + MS)
    assert budget.reserved == 100
    table.handle_timer(timed_out.connection.deadline - 1)
    assert budget.reserved == 100  # not a tick early
    table.handle_timer(timed_out.connection.deadline)
    assert budget.reserved == 0 and not table.connections


def test_a_listener_sharing_a_multicast_stream_needs_its_o_t_only() -> None:
    budget = CyclicBudget(1_000)
    table = table_with(budget)
    owner = table.forward_open(request(rpi_us=10_000, t_o_type=MULTICAST), ORIGINATOR, T0)
    assert type(owner) is Opened and budget.reserved == 200
    listener = table.forward_open(request(path=LISTEN_ONLY_PATH, o_t_size=2, rpi_us=10_000, t_o_type=MULTICAST),
                                  Originator("127.0.0.10"), T0)
    assert type(listener) is Opened and budget.reserved == 300


def test_lag_is_an_overload_past_its_limit_and_the_worst_is_kept_per_second() -> None:
    lag = Lag()
    second = 7_000_000_000
    assert lag.observe(OVERLOAD_LAG_NS, second) is False and lag.overloads == 0
    assert lag.observe(OVERLOAD_LAG_NS + 1, second + 1) is True and lag.overloads == 1
    assert lag.worst_ns == 0  # the second is not over yet
    lag.observe(10, second + 1_000_000_000)
    assert lag.worst_ns == OVERLOAD_LAG_NS + 1
    lag.observe(10, second + 2_000_000_000)
    assert lag.worst_ns == 10


@pytest.mark.integration  # loopback sockets: the cost of a datagram sent and read
def test_the_budget_measured_at_start_is_the_cost_of_a_pair_on_this_machine() -> None:
    budget = measure_budget([dsqc1030_profile()])
    pair_us = float(budget.source.split(": ")[1].split(" us")[0])
    assert 0.5 < pair_us < 500  # a real measurement, not a constant
    if "the machine gave" in budget.source:  # a busy machine: the share of a core it gave, less than UTILISATION
        share = float(budget.source.split("for the ")[1].split("%")[0]) / 100
        assert share < UTILISATION and budget.ceiling == pytest.approx(UTILISATION * 2e6 / pair_us, rel=0.01)
        assert budget.datagrams_per_s == pytest.approx(share * 2e6 / pair_us, rel=0.02, abs=100)
    else:
        assert budget.datagrams_per_s == budget.ceiling == pytest.approx(UTILISATION * 2e6 / pair_us, rel=0.01)


@pytest.mark.integration
def test_a_farm_past_its_budget_refuses_0x0113_and_keeps_the_others(enip_farm) -> None:
    farm = enip_farm({"cyclic_io": {"budget_datagrams_per_s": 450},
                      "devices": [{"name": n, "model": "DSQC1030"} for n in ("a", "b", "c")]}, http=True)
    a, b, c = farm.device("a"), farm.device("b"), farm.device("c")
    assert farm.budget.datagrams_per_s == 450 and farm.budget.source == "configured"
    with RawClient(a.profile.address) as ca, RawClient(b.profile.address) as cb, \
            RawClient(c.profile.address) as cc:
        for client in (ca, cb, cc):
            client.register()
        message, triad = forward_open(rpi=10_000, multiplier=7)
        assert ca.request(message).general_status == 0
        assert cb.request(forward_open(rpi=10_000, multiplier=7)[0]).general_status == 0
        refused = cc.request(forward_open(rpi=10_000, multiplier=7)[0])
        assert (refused.general_status, list(refused.additional_status)) == (0x01, [0x0113])
        metrics = httpx.get(f"http://127.0.0.1:{farm.http.port}/metrics").text
        assert metric_samples(metrics, "enip_farm_cyclic_io_budget_datagrams_per_second") == {(): 450.0}
        assert metric_samples(metrics, "enip_farm_cyclic_io_reserved_datagrams_per_second") == {(): 400.0}
        assert metric_samples(metrics, "enip_farm_cyclic_io_budget_refusals_total") == {(): 1.0}
        assert ca.request(forward_close(triad)).general_status == 0
        assert farm.budget.reserved == 200
        assert cc.request(forward_open(rpi=10_000, multiplier=7)[0]).general_status == 0


def test_kernel_drops_are_read_per_address_from_the_udp_table(tmp_path) -> None:
    from enip_farm.control.metrics import udp_drops

    table = tmp_path / "udp"
    table.write_text(
        "   sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode ref "
        "pointer drops\n"
        "  1: 010A007F:08AE 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 1 2 "
        "0000000000000000 17\n"
        "  2: 020A007F:08AE 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 2 2 "
        "0000000000000000 0\n"
        "  3: 010A007F:AF12 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 3 2 "
        "0000000000000000 5\n")
    assert udp_drops(2222, table) == {"127.0.10.1": 17, "127.0.10.2": 0}
    assert udp_drops(2222, tmp_path / "missing") == {}


def test_the_share_of_a_core_is_one_value_in_the_config_and_the_docs() -> None:
    assert f"{UTILISATION:.0%} of a core" in CyclicIoConfig.model_fields["budget_datagrams_per_s"].description
    share = f"{UTILISATION * 100:.0f} % of a core"
    assert share in (ROOT / "docs" / "implicit-io.md").read_text()
    assert share in (ROOT / "docs" / "benchmarks.md").read_text()


def test_the_running_check_lowers_the_budget_to_the_cpu_per_datagram_it_sees() -> None:
    budget = CyclicBudget(100_000, "measured at start: 10.0 us of CPU per O->T/T->O pair, for 50% of a core")
    # 50 000 datagrams on 0.4 s of CPU: 8 us each; half a core carries 62 500 a second
    budget.observe(400_000_000, 50_000, 1000, 0)
    assert budget.datagrams_per_s == round(UTILISATION * 1e9 / 8_000, -2) == 62_500
    assert budget.source == "lowered running: 8.00 us of CPU per datagram in the I/O thread, for 50% of a core"
    assert budget.lowered == 1
    budget.observe(100_000_000, 50_000, 1000, 0)  # cheaper now: no rise before CALM_SECONDS on time
    assert budget.datagrams_per_s == 62_500
    for _ in range(CALM_SECONDS - 2):
        budget.observe(100_000_000, 50_000, 1000, 0)
    assert budget.datagrams_per_s == 62_500
    budget.observe(100_000_000, 50_000, 1000, 0)  # the CALM_SECONDS-th: up to the start figure, never past it
    assert (budget.datagrams_per_s, budget.source) == (
        100_000, "measured at start: 10.0 us of CPU per O->T/T->O pair, for 50% of a core")


def test_a_budget_set_below_its_ceiling_rises_to_it_once_the_thread_keeps_time() -> None:
    """Measured on a busy machine: the share of a core it gave; the CPU figure is the ceiling. Idle
    seconds do not raise it (nothing shows the thread would keep time); a busy second on time does."""
    budget = CyclicBudget(0, "not started")
    budget.set(40_000, "measured at start: busy", ceiling=100_000)
    for _ in range(CALM_SECONDS * 2):
        budget.observe(1_000, 0, 0, 0)
    assert (budget.datagrams_per_s, budget.source) == (40_000, "measured at start: busy")
    assert budget.reserve(30_000) is not None
    for _ in range(CALM_SECONDS):  # 30 000 taken and moved on 0.1 s of CPU (3.3 us each), on time
        budget.observe(100_000_000, 30_000, 1000, 0)
    assert budget.datagrams_per_s == 100_000
    assert budget.source == "raised running: 3.33 us of CPU per datagram in the I/O thread, 10 s on time"


def test_a_second_with_few_datagrams_says_nothing() -> None:
    budget = CyclicBudget(100_000, "measured")
    budget.observe(900_000_000, MIN_DATAGRAMS - 1, 1000, 1000)  # expensive and late, but a few connections only
    assert (budget.datagrams_per_s, budget.lowered) == (100_000, 0)


def test_a_budget_held_as_its_connections_closed_rises_again_while_idle() -> None:
    """Held at what was taken in a late second, then everything closed: idle seconds count as on
    time, and the budget is back at its start figure after CALM_SECONDS (not stuck at 0)."""
    budget = CyclicBudget(100_000, "measured")
    taken = budget.reserve(MIN_DATAGRAMS)
    budget.release(taken)  # closed: 0 taken
    budget.observe(100_000_000, MIN_DATAGRAMS, 100, 50)  # the closing second, late
    assert budget.datagrams_per_s == 0
    for _ in range(CALM_SECONDS - 1):
        budget.observe(1_000, 0, 0, 0)
    assert budget.datagrams_per_s == 0
    budget.observe(1_000, 0, 0, 0)
    assert (budget.datagrams_per_s, budget.source) == (100_000, "measured")


def test_more_than_one_percent_of_turns_late_holds_the_budget_at_what_is_taken() -> None:
    budget = CyclicBudget(100_000, "measured")
    assert budget.reserve(30_000) is not None
    budget.observe(100_000_000, 30_000, 1000, 10)  # 1 %: on time
    assert budget.datagrams_per_s == 100_000
    budget.observe(100_000_000, 30_000, 1000, 11)  # more than 1 % late by more than LAG_LIMIT_NS
    assert budget.datagrams_per_s == 30_000
    assert budget.source == ("held at what is taken: 11 of 1000 turns of the I/O thread in a second ran more "
                             "than 2 ms late")
    assert budget.reserve(200) is None and budget.refused == 1
    for _ in range(CALM_SECONDS):  # on time again, the CPU per datagram allowing the start figure
        budget.observe(100_000_000, 30_000, 1000, 0)
    assert budget.datagrams_per_s == 100_000 and budget.reserve(200) is not None


def test_a_thread_starved_of_the_cpu_is_judged_by_what_it_has_taken() -> None:
    """It moves fewer datagrams than MIN_DATAGRAMS a second because it is late, not idle: with that
    much taken, its late turns hold the budget."""
    budget = CyclicBudget(100_000, "measured")
    assert budget.reserve(MIN_DATAGRAMS) is not None
    budget.observe(50_000_000, MIN_DATAGRAMS // 4, 40, 30)
    assert (budget.datagrams_per_s, budget.lowered) == (MIN_DATAGRAMS, 1)
    for _ in range(CALM_SECONDS):  # then on time, still few moved (no cost seen): back to the start figure
        budget.observe(50_000_000, MIN_DATAGRAMS // 4, 1000, 0)
    assert (budget.datagrams_per_s, budget.source) == (100_000, "measured")


def test_the_thread_side_counts_a_second_and_reads_its_cpu_once_a_second() -> None:
    budget = CyclicBudget(100_000, "measured")
    cpu = iter([1_000_000_000, 1_500_000_000, 9_000_000_000])
    running = RunningBudget(budget, lambda: next(cpu))
    running.tick(T0)  # the first second starts: CPU read
    running.datagrams += MIN_DATAGRAMS
    for lag in (0, LAG_LIMIT_NS, LAG_LIMIT_NS + 1):
        running.turn(lag)
    assert (running.turns, running.late_turns) == (3, 1)
    running.tick(T0 + 999_999_999)  # not a second yet: the CPU is not read
    assert budget.lowered == 0
    running.tick(T0 + 1_000_000_000)  # 0.5 s of CPU, 1 of 3 turns late: held at what is taken (nothing)
    assert budget.datagrams_per_s == 0 and budget.lowered == 1
    assert (running.datagrams, running.turns, running.late_turns) == (0, 0, 0)


def test_a_window_held_up_past_a_second_is_counted_per_second() -> None:
    """A loop held up for 3 s (a busy machine): its datagrams are 1/3 as many per second, too few to
    say anything; the CPU per datagram is the same."""
    budget = CyclicBudget(100_000, "measured")
    cpu = iter([0, 900_000_000, 900_000_000, 1_800_000_000])
    running = RunningBudget(budget, lambda: next(cpu))
    running.tick(T0)
    running.datagrams += MIN_DATAGRAMS * 2
    running.turn(LAG_LIMIT_NS + 1)
    running.tick(T0 + 3_000_000_000)  # 2/3 of MIN_DATAGRAMS a second: nothing said
    assert (budget.datagrams_per_s, budget.lowered) == (100_000, 0)
    running.tick(T0 + 4_000_000_000)  # a quiet second: nothing
    running.datagrams += 3 * MIN_DATAGRAMS  # then 3 s of 60 000 datagrams on 0.9 s of CPU: 15 us each
    running.tick(T0 + 7_000_000_000)
    assert budget.datagrams_per_s == round(UTILISATION * 1e9 / 15_000, -2)


def test_a_configured_budget_is_not_checked() -> None:
    running = RunningBudget(None, lambda: 0)
    running.tick(T0)
    running.datagrams += 50_000
    running.tick(T0 + 2_000_000_000)  # nothing to hand the figures to; no error
    assert running.datagrams == 0


@pytest.mark.integration  # loopback sockets
def test_the_budget_is_measured_over_the_workers_devices_and_leaves_nothing_open() -> None:
    """One scratch device per device of the worker (here 3), each with its loopback socket: the
    cost is a real one, and every socket, the epoll and the wake-up pipe are closed after."""
    import os

    opened = set(os.listdir("/proc/self/fd"))
    budget = measure_budget([dsqc1030_profile()] * 3)
    assert set(os.listdir("/proc/self/fd")) <= opened
    pair_us = float(budget.source.split(": ")[1].split(" us")[0])
    assert 0.5 < pair_us < 500
