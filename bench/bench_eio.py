"""EIO.cfg benchmark: how long `eio import` and `eio export` take for a large cell.

Generates an EIO.cfg of N DSQC1030 devices with 10/10-byte assemblies, each with S named signals
(DI, DO, GI, GO, AI), then times, in this process: parsing the file, importing it (every device
built and every signal checked against it), writing the YAML, and exporting the imported cell
back to EIO.cfg. Reported: seconds per step (best of R runs) and the file's size. No sockets.

    python bench/bench_eio.py [--devices 500] [--signals 40] [--runs 3]
"""

from __future__ import annotations

import argparse
import time
from ipaddress import IPv4Address

from enip_farm.config import parse_config
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.eio.cfg import parse_cfg, write_cfg
from enip_farm.eio.exporter import export_eio
from enip_farm.eio.importer import import_eio


def make_cfg(devices: int, signals: int) -> str:
    device_entries, signal_entries = [], []
    for d in range(devices):
        name = f"io{d + 1}"
        address = f"10.{d // 250}.{d % 250}.1"
        device_entries.append([
            ("Name", name), ("VendorName", "ABB Robotics"), ("Address", address), ("VendorId", 75),
            ("ProductCode", 1030), ("DeviceType", 7), ("OutputAssembly", 100), ("InputAssembly", 101),
            ("ConfigurationAssembly", 1), ("ConnectionPriority", "SCHEDULE"), ("OutputSize", 10), ("InputSize", 10)])
        for s in range(signals):
            kind, device_map = [("DI", f"{s % 16}"), ("DO", f"{s % 16}"), ("GI", "16-23"), ("GO", "16-31"),
                                ("AI", "64-79")][s % 5]
            signal = [("Name", f"{kind.lower()}{name}_{s}"), ("SignalType", kind), ("Device", name),
                      ("DeviceMap", device_map), ("Label", f"signal {s} of {name}")]
            signal_entries.append(signal + ([("Invert", True)] if s % 7 == 0 and kind in ("DI", "DO") else []))
    return write_cfg("EIO:CFG_1.0:7:0::", [("ETHERNETIP_DEVICE", device_entries), ("EIO_SIGNAL", signal_entries)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--devices", type=int, default=500)
    parser.add_argument("--signals", type=int, default=40, help="named signals per device")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    text = make_cfg(args.devices, args.signals)
    catalogue = shipped_catalogue()
    best: dict[str, float] = {}
    for _ in range(args.runs):
        steps = {}
        start = time.perf_counter()
        cfg = parse_cfg(text, "bench.cfg")
        steps["parse"] = time.perf_counter() - start
        start = time.perf_counter()
        result = import_eio(cfg, catalogue, IPv4Address("127.0.20.1"))
        steps["import (incl. YAML text)"] = time.perf_counter() - start
        start = time.perf_counter()
        exported = export_eio(parse_config(result.document), catalogue)
        steps["export (incl. building the cell)"] = time.perf_counter() - start
        for step, seconds in steps.items():
            best[step] = min(best.get(step, seconds), seconds)
    print(f"{args.devices} devices, {args.devices * args.signals} signals, EIO.cfg {len(text) / 1e6:.2f} MB, "
          f"{len(text.splitlines())} lines; import warnings: {len(result.warnings)}; "
          f"export {len(exported) / 1e6:.2f} MB")
    for step, seconds in best.items():
        print(f"  {step:34} {seconds:7.3f} s (best of {args.runs})")


if __name__ == "__main__":
    main()
