"""Cyclic-load benchmark: N exclusive-owner class-1 connections at an RPI, against the farm and, in
the same run, against a minimal C responder of the same shape (the ceiling).

Two C programs do the timing-critical work; this script builds them with the system compiler
(`cc`, or $CC) into bench/build/ whenever the source is newer than the binary:

    cc -O2 -pthread -o bench/build/cyclic_originator bench/cyclic_originator.c
    cc -O2 -o bench/build/cyclic_responder bench/cyclic_responder.c

For each row (N connections at RPI R):
1. the farm: a config of N DSQC1030 on 127.x addresses (250 per /24 from --first-address),
   `enip-farm serve --quiet --workers W` (taskset with --farm-cpus), wait until all listen; one
   Forward Open per device from Python (bench_implicit.py's session: exclusive owner, T->O point to
   point to the originator's UDP port in a 0x8001 item; refusals counted by their status, e.g.
   `0x01/0x0113` (the worker's cyclic I/O budget, which the farm's banner prints beside them), only
   admitted connections measured); the C originator (cyclic_originator.c: O->T on absolute
   deadlines with sendmmsg, T->O with recvmmsg and kernel receive timestamps) inherits those UDP
   sockets (one per pair of its threads: one pair per 2500 connections, --originator-threads),
   warms up, measures a window of --seconds, then keeps sending while every connection is
   Forward Closed (0x01/0x0107 = the farm had timed it out: a spurious timeout when the originator
   sent on time, its `sends late` column says whether it did); then the farm stops.
2. the ceiling: cyclic_responder.c on the same addresses (one socket per device, epoll, one
   receive and one send per datagram, T->O at the RPI), driven by the same originator the same way.

The originator's threads run SCHED_FIFO (--realtime, default priority 10; root) so that other load
on the machine does not make it late; its `late sends` column (sends more than 1 ms after their
deadline, and the latest) says whether it kept time: a timeout is the farm's own when no send was
late by anything near the timeout (RPI x 16 with the default --timeout-multiplier 2).
CPU (utime + stime from /proc, every process of the farm; % of one core) and kernel drops (the
drops column of /proc/net/udp for the farm's and the originator's sockets; /proc/net/snmp Udp
RcvbufErrors + InErrors for the whole host) are read when the originator says the window starts
and ends.
Pairs per CPU second = (O->T sent - dropped at the receiver's sockets + T->O received) / 2 in the
window / CPU seconds of the farm (or of the responder) in the window; the ratio is farm / C.
The farm runs its class-1 connections on the native path (server/native.py) and, in the same row,
on the Python one (`cyclic_io: {native: off}`), interleaved (--native both, the default).
Every loop is bounded in count and time; traffic goes to 127.0.0.0/8 only.

    python bench/bench_cyclic.py                   # the six rows, 60 s each (+ the same against C)
    python bench/bench_cyclic.py --quick           # the same rows, 3 s each
    python bench/bench_cyclic.py --rows 1600@10 --seconds 20    # past the farm's budget
    python bench/bench_cyclic.py --measure-cost --no-responder --repeat 3   # what the report's measurement costs
    python bench/bench_cyclic.py --native off      # the farm on the Python class-1 path only (default: both)
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import selectors
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from bench_implicit import CM, PATH, Session, address

from enip_farm.protocol.cip import encode_request
from enip_farm.protocol.commands import SocketAddress, encode_sockaddr
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardCloseRequest,
    ForwardOpenRequest,
    NetworkParameters,
    decode_forward_open_reply,
    encode_forward_close,
    encode_forward_open,
)
from enip_farm.protocol.cpf import ItemType

HERE = Path(__file__).resolve().parent
BUILD = HERE / "build"
DEFAULT_ROWS = "100@10,300@10,500@10,1000@10,100@2,200@2"
FIRST_ADDRESS = "127.0.230.1"
O_T_SIZE = 8  # DSQC1030: 2-byte sequence count + 4-byte run/idle header + 2 bytes of outputs
T_O_SIZE = 4  # 2-byte sequence count + 2 bytes of inputs
START_TIMEOUT = 180.0
LINE_TIMEOUT_MARGIN = 30.0
CLK_TCK = os.sysconf("SC_CLK_TCK")


def build(name: str, extra: tuple[str, ...] = ()) -> Path:
    """bench/build/NAME from bench/NAME.c with the system compiler, when the source is newer."""
    source, binary = HERE / f"{name}.c", BUILD / name
    if not binary.exists() or binary.stat().st_mtime < source.stat().st_mtime:
        BUILD.mkdir(exist_ok=True)
        compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
        if compiler is None:
            raise SystemExit("no C compiler: install one (Debian: apt-get install gcc)")
        subprocess.run([compiler, "-O2", "-Wall", *extra, "-o", str(binary), str(source)], check=True, timeout=120)
    return binary


def taskset(cpus: str | None) -> list[str]:
    return ["taskset", "-c", cpus] if cpus else []


def descendants(pid: int) -> list[int]:
    """pid and every process below it (the farm's parent, its workers, their helpers)."""
    found, todo = [], [pid]
    while todo and len(found) < 1000:
        current = todo.pop()
        found.append(current)
        try:
            for task in os.listdir(f"/proc/{current}/task"):
                todo += [int(c) for c in Path(f"/proc/{current}/task/{task}/children").read_text().split()]
        except (FileNotFoundError, ProcessLookupError):
            continue
    return found


def cpu_seconds(pids: list[int], fields_of: tuple[int, ...] = (11, 12)) -> float:
    """utime + stime of these processes (`fields_of=(11,)`: user time only, `(12,)`: system), seconds."""
    total = 0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            continue
        total += sum(int(fields[i]) for i in fields_of)
    return total / CLK_TCK


def socket_inodes(pids: list[int]) -> set[int]:
    inodes = set()
    for pid in pids:
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                try:
                    target = os.readlink(f"/proc/{pid}/fd/{fd}")
                except OSError:
                    continue
                if target.startswith("socket:["):
                    inodes.add(int(target[8:-1]))
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue
    return inodes


def udp_drops(inodes: set[int]) -> int:
    """The drops column of /proc/net/udp summed over these sockets."""
    total = 0
    with open("/proc/net/udp") as table:
        next(table)
        for line in table:
            fields = line.split()
            if len(fields) >= 13 and int(fields[9]) in inodes:
                total += int(fields[12])
    return total


def host_busy_seconds() -> float:
    """CPU time every CPU of the host spent busy (/proc/stat: all but idle and iowait)."""
    fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(fields[:8]) - fields[3] - fields[4]) / CLK_TCK


def snmp_udp_errors() -> int:
    """Host-wide UDP RcvbufErrors + InErrors (/proc/net/snmp)."""
    lines = [line.split() for line in Path("/proc/net/snmp").read_text().splitlines() if line.startswith("Udp:")]
    values = dict(zip(lines[0][1:], map(int, lines[1][1:]), strict=False))
    return values.get("RcvbufErrors", 0) + values.get("InErrors", 0)


@dataclass
class Connection:
    host: str
    o_t_id: int
    t_o_id: int
    session: Session | None = None
    triad: ConnectionTriad | None = None


def originator_socket() -> socket.socket:
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    size = 16 << 20
    try:
        udp.setsockopt(socket.SOL_SOCKET, 33, size)  # SO_RCVBUFFORCE (root), past net.core.rmem_max
    except OSError:
        udp.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
    udp.bind(("127.0.0.1", 0))
    return udp


def write_farm_config(path: Path, count: int, first: str, implicit: str = "", measure: bool = True,
                      budget: str = "auto", native: bool = True, realtime: int = 0) -> None:
    """N DSQC1030; the watchdog before the first O->T is 60 s (the default 10 s could pass while
    Python opens 1600 connections on a busy machine, and it is not what this measures). `measure`:
    the report's measurement of every O->T stream (`cyclic_io: {measure: false}` turns it off);
    `budget`: each worker's `cyclic_io.budget_datagrams_per_s` (auto, or a number); `native`: the
    native class-1 path where built (`cyclic_io: {native: auto}`), else the Python one (`off`);
    `realtime`: the cyclic I/O thread's SCHED_FIFO priority (`cyclic_io.realtime_priority`, 0: none)."""
    with path.open("w") as config:
        config.write(f"discovery: false\ncyclic_io: {{measure: {'true' if measure else 'false'}, "
                     f"budget_datagrams_per_s: {budget}, native: {'auto' if native else repr('off')}, "
                     f"realtime_priority: {realtime}}}\ndevices:\n")
        for i in range(count):
            config.write(f"  - {{name: c{i}, address: {address(i, first)}, model: DSQC1030, "
                         f"implicit: {{first_watchdog_s: 60{', ' + implicit if implicit else ''}}}}}\n")


def start_farm(config: Path, workers: int, cpus: str | None, log: Path, attempts: int = 3) -> subprocess.Popen:
    """`enip-farm serve` once every device listens. A port that is in use for a moment (a listener on
    0.0.0.0:44818 somewhere else on a shared machine takes every address) is tried again."""
    for attempt in range(1, attempts + 1):
        try:
            return _start_farm(config, workers, cpus, log)
        except PortInUse as error:
            print(f"  {error}; {'trying again in 2 s' if attempt < attempts else 'giving up'}",
                  file=sys.stderr, flush=True)
            if attempt == attempts:
                raise SystemExit(str(error)) from None
            time.sleep(2)
    raise AssertionError("unreachable")


class PortInUse(Exception):
    pass


def _start_farm(config: Path, workers: int, cpus: str | None, log: Path) -> subprocess.Popen:
    out = log.with_suffix(".out")
    with out.open("w") as stdout, log.open("w") as stderr:
        farm = subprocess.Popen([*taskset(cpus), sys.executable, "-m", "enip_farm", "serve", "--quiet",
                                 "--workers", str(workers), "--config", str(config)],
                                stdout=stdout, stderr=stderr, text=True)
    deadline = time.monotonic() + START_TIMEOUT
    while time.monotonic() < deadline:  # the device table's header: every device listens
        if out.read_text().strip():
            return farm
        if farm.poll() is not None:
            errors = log.read_text()[-2000:]
            if "already in use" in errors:
                raise PortInUse(f"the farm could not bind: {errors.strip().splitlines()[-1]}")
            raise SystemExit(f"the farm exited with {farm.returncode}: {errors}")
        time.sleep(0.1)
    farm.kill()
    raise SystemExit("the farm did not listen in time")


def started(pid: int) -> int | None:
    """The process's start time (clock ticks after boot), None once it has gone or is a zombie:
    with the pid, it names one process even after the pid is reused."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None if fields[0] == "Z" else int(fields[19])


def stop(process: subprocess.Popen, timeout: float = 60.0) -> None:
    """SIGTERM, then wait until the process and every process below it (the farm's workers) have
    gone, SIGKILL for any left after `timeout`: the next run binds the same addresses."""
    below = [(pid, started(pid)) for pid in descendants(process.pid)[1:]]
    below = [(pid, start) for pid, start in below if start is not None]
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and (process.poll() is None
                                           or any(started(pid) == start for pid, start in below)):
        time.sleep(0.05)
    for pid, start in below:
        if started(pid) == start:  # still the same process
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
    if process.poll() is None:
        process.kill()
    process.wait(10)


def status_text(general: int, additional: tuple[int, ...]) -> str:
    """e.g. `0x01/0x0113`: a refusal's general status and its extended status (the first word)."""
    return f"0x{general:02X}" + (f"/0x{additional[0]:04X}" if additional else "")


def forward_open(hosts: list[str], rpi_us: int, port: int | list[int],
                 multiplier: int = 2) -> tuple[list[Connection], Counter[str]]:
    """One exclusive-owner connection per host, connection i's T->O to `port` (or to port[i % len]):
    (the admitted ones, the refused ones counted by status, e.g. `0x01/0x0113`, and by `OSError: ...`
    when the session failed). The farm times a connection out after RPI x 2^(2 + multiplier) without O->T."""
    ports = port if isinstance(port, list) else [port]
    opened: list[Connection] = []
    refused: Counter[str] = Counter()
    for i, host in enumerate(hosts):
        try:
            session = Session(host)
        except OSError as error:  # the farm's TCP limits, or this process's open files
            refused[f"OSError: {error.strerror or error}"] += 1
            continue
        triad = ConnectionTriad(i + 1, 0x0BE0, 0x12345678)
        request = ForwardOpenRequest(0x0A, 0x0E, 0, 0x70000000 + i, triad, multiplier, rpi_us,
                                     NetworkParameters(False, ConnectionType.POINT_TO_POINT, 2, False, O_T_SIZE),
                                     rpi_us,
                                     NetworkParameters(False, ConnectionType.POINT_TO_POINT, 2, False, T_O_SIZE),
                                     0x01, PATH)
        try:
            reply = session.request(encode_request(0x54, CM, encode_forward_open(request)), [(
                ItemType.SOCKADDR_T_O, encode_sockaddr(SocketAddress("0.0.0.0", ports[i % len(ports)])))])
        except OSError as error:
            refused[f"OSError: {error.strerror or error}"] += 1
            session.sock.close()
            continue
        if reply.general_status:
            refused[status_text(reply.general_status, tuple(reply.additional_status[:1]))] += 1
            session.sock.close()
            continue
        ids = decode_forward_open_reply(reply.data)
        opened.append(Connection(host, ids.o_t_connection_id, ids.t_o_connection_id, session, triad))
    return opened, refused


def forward_close(connections: list[Connection]) -> tuple[int, int]:
    """Close every connection; (timed out by the farm: 0x0107, other errors)."""
    timeouts = errors = 0
    for connection in connections:
        assert connection.session is not None and connection.triad is not None
        try:
            reply = connection.session.request(encode_request(0x4E, CM, encode_forward_close(
                ForwardCloseRequest(0x0A, 0x0E, connection.triad, PATH))))
            if reply.general_status == 0x01 and reply.additional_status[:1] == (0x0107,):
                timeouts += 1
            elif reply.general_status:
                errors += 1
        except OSError:
            errors += 1
        finally:
            connection.session.sock.close()
    return timeouts, errors


def read_line(stream, timeout: float) -> str:
    """A line of `stream` within `timeout` s, or "" (poll-based: any file descriptor, past 1024 too)."""
    with selectors.DefaultSelector() as selector:
        selector.register(stream, selectors.EVENT_READ)
        ready = selector.select(timeout)
    return stream.readline().strip() if ready else ""


def drive(binary: Path, connections: list[Connection], rpi_us: int, udp: list[socket.socket], seconds: float,
          warmup: float, cpus: str | None, peer_pids: list[int], work: Path, during_hold=None,
          realtime: int = 0, profile: Path | None = None) -> dict:
    """Run the originator over `connections`, connection i's T->O on `udp[i % len(udp)]` (one pair of
    its threads per socket); its figures plus CPU and drops sampled over its window."""
    listing = work / "originator.txt"
    listing.write_text("".join(f"{c.host} {c.o_t_id} {c.t_o_id} {rpi_us} {O_T_SIZE} {T_O_SIZE}\n"
                               for c in connections))
    out = work / "originator.json"
    fds = [u.fileno() for u in udp]
    originator = subprocess.Popen([*taskset(cpus), str(binary), "--connections", str(listing),
                                   "--fd", ",".join(map(str, fds)),
                                   "--seconds", str(seconds), "--warmup", str(warmup), "--hold", "300",
                                   "--realtime", str(realtime),
                                   "--json", str(out)],
                                  pass_fds=fds, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        peer_inodes = socket_inodes(peer_pids)
        own_inode = {os.fstat(fd).st_ino for fd in fds}

        def sample() -> tuple[float, float, int, int, int, float, float, float]:
            return (cpu_seconds(peer_pids), cpu_seconds([originator.pid]), udp_drops(peer_inodes),
                    udp_drops(own_inode), snmp_udp_errors(), host_busy_seconds(), cpu_seconds(peer_pids, (11,)),
                    os.getloadavg()[0])

        if read_line(originator.stdout, warmup + LINE_TIMEOUT_MARGIN) != "start":
            raise SystemExit("the originator did not start its window")
        before, wall0 = sample(), time.monotonic()
        spies = py_spy(peer_pids, seconds, profile) if profile else []
        if read_line(originator.stdout, seconds + LINE_TIMEOUT_MARGIN) != "end":
            raise SystemExit("the originator did not end its window")
        after, wall1 = sample(), time.monotonic()
        for spy in spies:
            spy.wait(LINE_TIMEOUT_MARGIN)
        extra = during_hold() if during_hold else {}
        originator.stdin.close()
        originator.wait(60)
    finally:
        if originator.poll() is None:
            originator.kill()
            originator.wait(10)
    figures = json.loads(out.read_text())
    wall = wall1 - wall0
    figures.update(extra)
    figures.update({
        "peer_cpu_s": after[0] - before[0], "peer_cpu_percent": 100 * (after[0] - before[0]) / wall,
        "peer_user_percent": 100 * (after[6] - before[6]) / wall,
        "peer_system_percent": 100 * ((after[0] - before[0]) - (after[6] - before[6])) / wall,
        "load_average": after[7],
        "originator_cpu_percent": 100 * (after[1] - before[1]) / wall,
        "peer_socket_drops": after[2] - before[2], "originator_socket_drops": after[3] - before[3],
        "host_udp_errors": after[4] - before[4],
        # what else kept the host busy in the window (other programs, this script, the kernel's own work)
        "other_cpu_percent": 100 * ((after[5] - before[5]) - (after[0] - before[0]) - (after[1] - before[1])) / wall,
    })
    delivered = figures["o_t_sent_window"] - figures["peer_socket_drops"]
    figures["o_t_received_window"] = delivered
    pairs = (delivered + figures["t_o_received_window"]) / 2
    figures["pairs_per_cpu_s"] = pairs / figures["peer_cpu_s"] if figures["peer_cpu_s"] > 0 else float("nan")
    return figures


def originator_threads(args: argparse.Namespace, count: int) -> int:
    """Pairs of originator threads (one socket each): --originator-threads, else one per 2500 connections."""
    return args.originator_threads or min(8, max(1, -(-count // 2500)))


def farm_budgets(log: Path) -> list[str]:
    """What the farm's banner says of each worker's cyclic I/O budget."""
    return [line.strip() for line in log.read_text(errors="replace").splitlines() if "cyclic I/O budget:" in line]


def py_spy(pids: list[int], seconds: float, directory: Path) -> list[subprocess.Popen]:
    """`py-spy record` (pip install py-spy; root) of every Python process of the farm over the window,
    raw stacks into DIRECTORY/farm-PID.txt (`python bench/profile_summary.py` or a flame graph reads them)."""
    binary = shutil.which("py-spy")
    if binary is None:
        raise SystemExit("--py-spy needs py-spy (pip install py-spy)")
    directory.mkdir(parents=True, exist_ok=True)
    return [subprocess.Popen([binary, "record", "--pid", str(pid), "--duration", str(max(1, int(seconds))),
                              "--rate", "200", "--format", "raw", "--nonblocking",
                              "--output", str(directory / f"farm-{pid}.txt")],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for pid in pids if "python" in Path(f"/proc/{pid}/comm").read_text(errors="replace").lower()
            or "enip" in Path(f"/proc/{pid}/cmdline").read_text(errors="replace")]


def run_farm(count: int, rpi_us: int, args: argparse.Namespace, originator: Path, work: Path,
             measure: bool = True, native: bool = True) -> dict:
    config = work / "cell.yaml"
    write_farm_config(config, count, args.first_address, args.implicit, measure, args.budget, native,
                      args.farm_realtime)
    farm = start_farm(config, args.workers, args.farm_cpus, work / "farm.log")
    try:
        pids = descendants(farm.pid)
        udp = [originator_socket() for _ in range(originator_threads(args, count))]
        try:
            hosts = [address(i, args.first_address) for i in range(count)]
            t = time.monotonic()
            connections, refusals = forward_open(hosts, rpi_us, [u.getsockname()[1] for u in udp],
                                                 args.timeout_multiplier)
            opening = time.monotonic() - t
            refused = sum(refusals.values())
            budgets = farm_budgets(work / "farm.log")
            if refusals:
                print(f"  refused: {', '.join(f'{n} {why}' for why, n in refusals.most_common())}; "
                      f"{'; '.join(budgets)}", file=sys.stderr, flush=True)
            if not connections:
                raise SystemExit(f"every Forward Open was refused ({dict(refusals)})")
            closes: dict[str, int] = {}

            def close_all() -> dict:
                timeouts, errors = forward_close(connections)
                closes.update(timeouts=timeouts, close_errors=errors)
                return closes

            figures = drive(originator, connections, rpi_us, udp, args.seconds, args.warmup, args.originator_cpus,
                            pids, work, close_all, args.realtime, args.py_spy)
        finally:
            for u in udp:
                u.close()
    finally:
        stop(farm)
    # what the running check of an auto budget did (cip/budget.py): each change, said by the worker
    changes = [line.split(" WARNING ", 1)[-1] for line in (work / "farm.log").read_text(errors="replace").splitlines()
               if "cyclic I/O budget now" in line]
    if changes:
        print(f"  {len(changes)} budget changes while running, the last: {changes[-1]}", file=sys.stderr, flush=True)
    figures.update(offered=count, admitted=figures["connections"], refused=refused,
                   refusals=dict(refusals), budgets=budgets, budget_changes=changes, forward_open_s=opening)
    return figures


def run_responder(count: int, rpi_us: int, args: argparse.Namespace, originator: Path, responder: Path,
                  work: Path) -> dict:
    connections = [Connection(address(i, args.first_address), 0x10000 + i, 0x20000 + i) for i in range(count)]
    udp = [originator_socket() for _ in range(originator_threads(args, count))]
    try:
        listing = work / "responder.txt"
        ports = [u.getsockname()[1] for u in udp]
        listing.write_text("".join(f"{c.host} {c.o_t_id} {c.t_o_id} {rpi_us} {O_T_SIZE} {T_O_SIZE} 127.0.0.1 "
                                   f"{ports[i % len(ports)]}\n" for i, c in enumerate(connections)))
        process = subprocess.Popen([*taskset(args.responder_cpus), str(responder), "--connections", str(listing),
                                    "--seconds", str(args.warmup + args.seconds + 600)],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            if read_line(process.stdout, 30) != "ready":
                raise SystemExit(f"the C responder did not start: {process.stderr.read() if process.poll() else ''}")
            figures = drive(originator, connections, rpi_us, udp, args.seconds, args.warmup, args.originator_cpus,
                            [process.pid], work, realtime=args.realtime)
        finally:
            stop(process)
        counts = process.stdout.read().strip()
        figures["responder"] = json.loads(counts) if counts else {}
    finally:
        for u in udp:
            u.close()
    return figures


def medians(runs: list[dict]) -> dict:
    """Each figure's median over the runs (one run: itself, with its connections)."""
    if len(runs) == 1:
        return runs[0]
    merged = {}
    for key, value in runs[0].items():
        values = [run[key] for run in runs]
        if isinstance(value, bool) or not all(isinstance(v, int | float) for v in values):
            continue
        middle = statistics.median(values)
        merged[key] = round(middle) if all(isinstance(v, int) for v in values) else middle
    return merged


def parse_rows(text: str) -> list[tuple[int, float]]:
    rows = []
    for item in text.split(","):
        count, _, rpi = item.partition("@")
        rows.append((int(count), float(rpi)))
    return rows


def p99(figures: dict) -> str:
    return f"{figures['err_p99_ms']:.2f}" if figures["intervals"] else "-"


COLUMNS = [
    ("conns", lambda r: f"{r['farm']['admitted']}" + (f" (+{r['farm']['refused']} refused)" if r['farm']['refused']
                                                        else "")),
    ("RPI ms", lambda r: f"{r['rpi_ms']:g}"),
    ("O->T expected", lambda r: f"{r['farm']['o_t_sent_window']:,}"),
    ("O->T received", lambda r: f"{r['farm']['o_t_received_window']:,}"),
    ("T->O expected", lambda r: f"{r['farm']['t_o_expected_window']:,}"),
    ("T->O received", lambda r: f"{r['farm']['t_o_received_window']:,}"),
    ("lost", lambda r: f"{r['farm']['lost']:,}"),
    ("late", lambda r: f"{r['farm']['late']:,}"),
    ("timed out", lambda r: f"{r['farm']['timeouts']}"),
    ("originator late sends (latest ms)",
     lambda r: f"{r['farm']['sends_late']:,} ({r['farm']['send_lag_max_ms']:.1f})"),
    ("error p50/p99/max ms", lambda r: "-" if not r['farm']['intervals'] else
     f"{r['farm']['err_p50_ms']:.2f} / {r['farm']['err_p99_ms']:.2f} / {r['farm']['err_max_ms']:.1f}"),
    ("farm CPU %", lambda r: f"{r['farm']['peer_cpu_percent']:.0f}"),
    ("originator CPU %", lambda r: f"{r['farm']['originator_cpu_percent']:.0f}"),
    ("other CPU %", lambda r: f"{max(0.0, r['farm']['other_cpu_percent']):.0f}"),  # tick accounting can dip below 0
    ("kernel drops", lambda r: f"{r['farm']['peer_socket_drops'] + r['farm']['originator_socket_drops']:,} "
                               f"({r['farm']['host_udp_errors']:,})"),
    ("C responder: T->O received, p99 ms, CPU %", lambda r: "-" if not r.get("c") else
     f"{r['c']['t_o_received_window']:,}, {p99(r['c'])}, {r['c']['peer_cpu_percent']:.0f}"),
    ("pairs/CPU-s farm / C", lambda r: f"{r['farm']['pairs_per_cpu_s']:,.0f} / " +
     ("-" if not r.get("c") else f"{r['c']['pairs_per_cpu_s']:,.0f}")),
    ("ratio", lambda r: "-" if not r.get("c") else f"{r['farm']['pairs_per_cpu_s'] / r['c']['pairs_per_cpu_s']:.3f}"),
    # --native both: the farm again on the Python class-1 path (cyclic_io: {native: off}), interleaved
    ("Python path: T->O received, p99 ms, pairs/CPU-s, ratio to C", lambda r: "-" if not r.get("python") else
     f"{r['python']['t_o_received_window']:,}, {p99(r['python'])}, {r['python']['pairs_per_cpu_s']:,.0f}, " +
     ("-" if not r.get("c") else f"{r['python']['pairs_per_cpu_s'] / r['c']['pairs_per_cpu_s']:.3f}")),
    # --measure-cost: the farm again without the report's measurement; CPU per pair with it / without it - 1
    ("pairs/CPU-s unmeasured, measuring costs", lambda r: "-" if not r.get("unmeasured") else
     f"{r['unmeasured']['pairs_per_cpu_s']:,.0f}, "
     f"{(r['unmeasured']['pairs_per_cpu_s'] / r['farm']['pairs_per_cpu_s'] - 1) * 100:+.1f} %"),
]


def table(results: list[dict]) -> str:
    lines = ["| " + " | ".join(name for name, _ in COLUMNS) + " |",
             "|" + "|".join("---:" for _ in COLUMNS) + "|"]
    lines += ["| " + " | ".join(cell(r) for _, cell in COLUMNS) + " |" for r in results]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", default=DEFAULT_ROWS, help=f"CONNECTIONS@RPI_MS, comma-separated ({DEFAULT_ROWS})")
    parser.add_argument("--seconds", type=float, default=None, help="measured window per run (60; --quick: 3)")
    parser.add_argument("--warmup", type=float, default=None, help="sending before the window (2; --quick: 1)")
    parser.add_argument("--quick", action="store_true", help="a short smoke run: 3 s windows")
    parser.add_argument("--repeat", type=int, default=1, help="runs per row, farm and C interleaved; medians shown")
    parser.add_argument("--implicit", default="", metavar="YAML",
                        help="more of every device's `implicit:` settings, e.g. 'max_class1_connections: 0'")
    parser.add_argument("--timeout-multiplier", type=int, choices=range(8), default=2, metavar="0-7",
                        help="the Forward Open's: the farm's timeout is RPI x 2^(2 + this) (2: 16 RPI)")
    parser.add_argument("--workers", type=int, default=2, help="enip-farm serve --workers (2: the README's layout)")
    parser.add_argument("--farm-cpus", default=None, help="taskset -c list for the farm (default: not pinned)")
    parser.add_argument("--responder-cpus", default=None, help="taskset -c list for the C responder")
    parser.add_argument("--originator-cpus", default=None, help="taskset -c list for the C originator")
    parser.add_argument("--realtime", type=int, default=10, metavar="PRIORITY",
                        help="the originator's threads run SCHED_FIFO at this priority (root; 0: not), so that "
                             "the machine's other load does not make it late (10)")
    parser.add_argument("--farm-realtime", type=int, default=0, metavar="PRIORITY",
                        help="the farm's cyclic I/O threads run SCHED_FIFO at this priority (root; 0: not): "
                             "cyclic_io.realtime_priority")
    parser.add_argument("--budget", default="auto",
                        help="each worker's cyclic_io.budget_datagrams_per_s: auto (measured at start) or a number")
    parser.add_argument("--originator-threads", type=int, default=0, metavar="N",
                        help="pairs of originator threads (a socket each; default: one per 2500 connections, "
                             "at most 8), so that the originator is not the limit")
    parser.add_argument("--py-spy", type=Path, default=None, metavar="DIR",
                        help="record every farm process with py-spy over the window, raw stacks into DIR")
    parser.add_argument("--native", choices=("both", "on", "off"), default="both",
                        help="the farm's class-1 path: native (on: cyclic_io.native auto, where built), Python "
                             "(off), or both, interleaved (every other run the Python one goes first) (both)")
    parser.add_argument("--no-responder", action="store_true", help="leave out the C responder's runs")
    parser.add_argument("--measure-cost", action="store_true",
                        help="also run the farm with the report's measurement off (cyclic_io: {measure: false}), "
                             "interleaved (every other run it goes first): the CPU it costs per pair")
    parser.add_argument("--first-address", default=FIRST_ADDRESS,
                        help="the first device's address (127.0.0.0/8); 250 per /24 from there")
    parser.add_argument("--json", type=Path, default=None, help="also write every figure here")
    parser.add_argument("--keep", type=Path, default=None, metavar="DIR",
                        help="keep the configs, connection lists, logs and raw JSON of the last row here")
    parser.add_argument("--per-connection", action="store_true", help="with --json: each connection's figures too")
    args = parser.parse_args()
    args.seconds = args.seconds if args.seconds is not None else 3.0 if args.quick else 60.0
    args.warmup = args.warmup if args.warmup is not None else 1.0 if args.quick else 2.0
    if not address(0, args.first_address).startswith("127."):
        raise SystemExit("--first-address must be in 127.0.0.0/8")
    rows = parse_rows(args.rows)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))  # a TCP session per connection
    originator = build("cyclic_originator", ("-pthread",))
    responder = build("cyclic_responder")
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-cyclic-") as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for n, (count, rpi_ms) in enumerate(rows, 1):
            rpi_us = round(rpi_ms * 1000)
            runs = []
            for attempt in range(1, args.repeat + 1):
                print(f"row {n}/{len(rows)}, run {attempt}/{args.repeat}: {count} connections at RPI {rpi_ms:g} ms, "
                      f"{args.seconds:g} s: farm ...", file=sys.stderr, flush=True)
                run = {}
                if args.measure_cost and attempt % 2 == 0:  # every other run the unmeasured farm goes first
                    run["unmeasured"] = run_farm(count, rpi_us, args, originator, work, measure=False,
                                                 native=args.native != "off")
                python_first = args.native == "both" and attempt % 2 == 0
                if python_first:
                    run["python"] = run_farm(count, rpi_us, args, originator, work, native=False)
                run["farm"] = run_farm(count, rpi_us, args, originator, work, native=args.native != "off")
                farm = run["farm"]
                print(f"  farm: {farm['admitted']} admitted, {farm['refused']} refused, T->O "
                      f"{farm['t_o_received_window']}/{farm['t_o_expected_window']}, p99 {farm['err_p99_ms']:.2f} ms, "
                      f"{farm['timeouts']} timed out, {farm['sends_late']} late sends, "
                      f"CPU {farm['peer_cpu_percent']:.0f}% ({farm['peer_user_percent']:.0f}% user, "
                      f"{farm['peer_system_percent']:.0f}% system), load average {farm['load_average']:.2f}",
                      file=sys.stderr, flush=True)
                if args.native == "both":
                    if not python_first:
                        run["python"] = run_farm(count, rpi_us, args, originator, work, native=False)
                    p = run["python"]
                    print(f"  farm, Python path: {p['admitted']} admitted, T->O {p['t_o_received_window']}/"
                          f"{p['t_o_expected_window']}, p99 {p['err_p99_ms']:.2f} ms, {p['timeouts']} timed out, CPU "
                          f"{p['peer_cpu_percent']:.0f}%, {p['pairs_per_cpu_s']:,.0f} pairs/CPU-s (native: "
                          f"{farm['pairs_per_cpu_s']:,.0f})", file=sys.stderr, flush=True)
                if args.measure_cost:
                    if "unmeasured" not in run:
                        run["unmeasured"] = run_farm(count, rpi_us, args, originator, work, measure=False,
                                                 native=args.native != "off")
                    u = run["unmeasured"]
                    print(f"  farm, not measuring: {u['admitted']} admitted, CPU {u['peer_cpu_percent']:.0f}%, "
                          f"{u['pairs_per_cpu_s']:,.0f} pairs/CPU-s (measuring: {farm['pairs_per_cpu_s']:,.0f})",
                          file=sys.stderr, flush=True)
                if not args.no_responder:
                    c = run["c"] = run_responder(farm["admitted"], rpi_us, args, originator, responder, work)
                    print(f"  C responder: T->O {c['t_o_received_window']}/{c['t_o_expected_window']}, p99 "
                          f"{c['err_p99_ms']:.2f} ms, CPU {c['peer_cpu_percent']:.0f}% ({c['peer_user_percent']:.0f}% "
                          f"user, {c['peer_system_percent']:.0f}% system)", file=sys.stderr, flush=True)
                runs.append(run)
            result = {"connections": count, "rpi_ms": rpi_ms,
                      **{side: medians([run[side] for run in runs]) for side in runs[0]}}
            if len(runs) > 1:
                result["runs"] = runs
            results.append(result)
    print(f"{args.seconds:g} s windows{f', medians of {args.repeat} runs' if args.repeat > 1 else ''}, "
          f"farm: --workers {args.workers}, class-1 path {'native' if args.native != 'off' else 'Python'}"
          f"{' on CPUs ' + args.farm_cpus if args.farm_cpus else ''}")
    print(table(results))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        for result in results:
            for figures in [result, *result.get("runs", [])]:
                for side in ("farm", "c", "unmeasured", "python"):
                    if side in figures and not args.per_connection:
                        figures[side].pop("per_connection", None)
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "rows": results},
                                        indent=1))


if __name__ == "__main__":
    main()
