"""What a real scanner's jitter looks like on this machine (issue 27, item 5): three originators,
as they are, each holding one exclusive-owner class-1 connection to a DSQC1030 of one farm for
--seconds at --rpi-ms, one after the other; the farm's report (Farm.report(): the O->T packet
intervals from the kernel's receive times) gives each one's interval p50 / p99 / max against its RPI,
its intervals of 2 RPI or more and the verdicts of the default bounds.

- the `ethernetip` scanner (PyPI, the test extra), in a process of its own: registerAssembly,
  startIO, sendFwdOpenReq, produce() (its own thread sends the O->T);
- cm-ethernetip's standard scanner (PyPI `cm-ethernetip`, asyncio), in a venv of its own (its
  package `ethernetip` clashes with the other's), driven by tests/cm_ethernetip/originator.py;
- EIPScanner (C++, github.com/nimbuscontrols/EIPScanner) through bench/eipscanner_originator.cpp,
  built here against --eipscanner SRC (a checkout with BUILD=SRC/build made by cmake); left out
  when not given.

    python bench/real_scanners.py --eipscanner /tmp/eipscanner            # 20 s each at RPI 10 ms
    python bench/real_scanners.py --rpi-ms 4 --seconds 10 --cm-venv /tmp/cm

Traffic goes to 127.0.0.0/8 only; every wait is bounded.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from enip_farm.farm.farm import Farm  # noqa: E402

FIRST = "127.0.235.1"
LOCAL = "127.0.235.200"  # cm-ethernetip's own address: its UDP listens on LOCAL:2222
SCANNERS = ("ethernetip", "cm-ethernetip", "EIPScanner")


def drive_ethernetip(host: str, rpi_ms: float, seconds: float) -> None:
    """The `ethernetip` scanner against `host` (run in its own process by `main`)."""
    from tests.scanners import scanner

    with scanner(host, forward_close=True) as scan:
        status = scan.forward_open(round(rpi_ms), 2)  # whole ms
        if status != 0:
            raise SystemExit(f"Forward Open refused: {status}")
        scan.conn.produce()
        time.sleep(seconds)


def run_ethernetip(host: str, rpi_ms: float, seconds: float) -> str:
    subprocess.run([sys.executable, __file__, "--drive-ethernetip", host, str(rpi_ms), str(seconds)], check=True,
                   timeout=seconds + 60)
    return "ethernetip " + _version("ethernetip")


def run_cm(python: Path, host: str, rpi_ms: float, seconds: float) -> str:
    from tests.cm_ethernetip import VERSION, CmOriginator

    scanner = CmOriginator(python, {"mode": "standard", "host": host, "local": LOCAL, "output_size": 2,
                                    "input_size": 4, "rpi_us": round(rpi_ms * 1000)})
    try:
        opened = scanner.wait("open", timeout=30)
        if opened["event"] != "open":
            raise SystemExit(f"cm-ethernetip: {opened}")
        time.sleep(seconds)
    finally:
        scanner.close()
    return f"cm-ethernetip {VERSION}"


def build_eipscanner(source: Path) -> Path:
    binary = ROOT / "bench" / "build" / "eipscanner_originator"
    driver = ROOT / "bench" / "eipscanner_originator.cpp"
    if not binary.exists() or binary.stat().st_mtime < driver.stat().st_mtime:
        binary.parent.mkdir(exist_ok=True)
        subprocess.run(["g++", "-O2", "-std=c++20", "-I", str(source / "src"), "-o", str(binary), str(driver),
                        str(source / "build" / "src" / "libEIPScannerS.a")], check=True, timeout=300)
    return binary


def run_eipscanner(binary: Path, source: Path, host: str, rpi_ms: float, seconds: float) -> str:
    subprocess.run([str(binary), host, str(round(rpi_ms * 1000)), str(seconds)], check=True, timeout=seconds + 60,
                   stdout=subprocess.DEVNULL)
    commit = subprocess.run(["git", "-C", str(source), "log", "-1", "--format=%h"], capture_output=True, text=True)
    return f"EIPScanner {commit.stdout.strip() or '?'}"


def _version(package: str) -> str:
    from importlib.metadata import version

    return version(package)


def figures(farm: Farm, device: str) -> dict:
    (connection, *_) = farm.report().device(device).connections
    return connection.as_dict()


def row(name: str, rpi_ms: float, figures: dict) -> str:
    i = figures["intervals"]
    rpi_ns = rpi_ms * 1e6

    def ms(ns: int | None) -> str:
        return "-" if ns is None else f"{ns / 1e6:.2f}"

    failed = "; ".join(f"{v['figure']} ({v['value']})" for v in figures["verdicts"] if v["verdict"] == "fail")
    return (f"| {name} | {rpi_ms:g} | {i['count']:,} | {ms(i['mean_ns'])} | {ms(i['p50_ns'])} | {ms(i['p99_ns'])} | "
            f"{ms(i['max_ns'])} | "
            f"{(i['p99_ns'] or 0) / rpi_ns:.2f} | {i['late']} | {figures['sequence']['lost']} | "
            f"{failed or 'none'} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rpi-ms", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--eipscanner", type=Path, default=None, help="EIPScanner checkout, built in SRC/build")
    parser.add_argument("--cm-venv", type=Path, default=None, help="a venv with cm-ethernetip (made if missing)")
    parser.add_argument("--only", default=None, help=f"comma-separated, of {', '.join(SCANNERS)}")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--drive-ethernetip", nargs=3, metavar=("HOST", "RPI_MS", "SECONDS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.drive_ethernetip:
        host, rpi_ms, seconds = args.drive_ethernetip
        drive_ethernetip(host, float(rpi_ms), float(seconds))
        return
    from tests.cm_ethernetip import make_venv

    cm_root = args.cm_venv or Path(os.environ.get("TMPDIR", "/tmp")) / "enip-farm-cm-ethernetip-venv"
    cm_python = make_venv(cm_root) if not args.only or "cm-ethernetip" in args.only else Path()
    binary = build_eipscanner(args.eipscanner) if args.eipscanner else None
    prefix, last = FIRST.rsplit(".", 1)
    cell = {"discovery": False, "devices": [
        {"name": name, "address": f"{prefix}.{int(last) + i}", "model": "DSQC1030"}
        for i, name in enumerate(SCANNERS)]}
    rows, results = [], {}
    with Farm(cell).running_in_thread() as farm:
        for name in SCANNERS:
            if args.only and name not in args.only.split(","):
                continue
            host = farm[name].address
            if name == "ethernetip":
                label = run_ethernetip(host, args.rpi_ms, args.seconds)
            elif name == "cm-ethernetip":
                label = run_cm(cm_python, host, args.rpi_ms, args.seconds)
            elif binary is not None:
                label = run_eipscanner(binary, args.eipscanner, host, args.rpi_ms, args.seconds)
            else:
                continue
            results[label] = figures(farm, name)
            rows.append(row(label, args.rpi_ms, results[label]))
    print(f"{args.seconds:g} s each, one connection, the farm's report (kernel receive times), "
          f"{os.cpu_count()} CPUs")
    print("| originator | RPI ms | intervals | mean ms | p50 ms | p99 ms | max ms | p99 / RPI | ≥ 2 RPI | lost | "
          "failed verdicts (default bounds) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    print("\n".join(rows))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
