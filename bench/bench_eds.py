"""EDS import and serving, measured on a folder of real EDS files (default tests/data/eds/; point it
at any folder, e.g. a vendor's EDS library kept outside the repository):

- import: each file read (grammar), checked and made a profile; how many import, the median time
  per file, and the time for `--copies` copies of the folder (500 files with the default 50 x 10);
- serving: each imported file served by a farm on 127.0.0.1 (one at a time) and held against its
  EDS over CIP with the project's codec: identity attributes 1-4 and 7, every assembly instance's
  size, and a Forward Open per class-1 connection entry with the entry's own path, sizes and RPI
  (listen-only entries after a multicast owner of their T->O point). Prints the counts.

    python bench/bench_eds.py [FOLDER] [--copies 50] [--no-serve]
"""

from __future__ import annotations

import argparse
import statistics
import struct
import sys
import tempfile
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from enip_farm.eds.grammar import decode_eds_bytes  # noqa: E402
from enip_farm.eds.reader import EdsError, eds_profile, read_eds  # noqa: E402
from enip_farm.farm.farm import Farm  # noqa: E402
from tests.helpers import RawClient  # noqa: E402
from tests.test_eds_real import _close, _open, _path  # noqa: E402


def import_all(folder: Path) -> tuple[list[tuple[Path, object, dict]], list[str], list[float]]:
    imported, failed, times = [], [], []
    for path in sorted(p for p in folder.iterdir() if p.suffix.lower() == ".eds"):
        started = time.perf_counter()
        try:
            device = read_eds(decode_eds_bytes(path.read_bytes()), path.name)
            name, document, _ = eds_profile(device, path.name)
        except EdsError as error:
            failed.append(f"{path.name}: {str(error).splitlines()[0]}")
            continue
        finally:
            times.append(time.perf_counter() - started)
        imported.append((path, device, document["models"][name]))
    return imported, failed, times


def serve_and_check(path: Path, device, model: dict, workdir: Path) -> tuple[bool, int, int, list[str]]:
    """(identity and sizes right, entries accepted, entries, refusals) of one imported file."""
    profile = workdir / f"{path.stem}.yaml"
    profile.write_text(yaml.safe_dump({"models": {"m": model}}, sort_keys=False, allow_unicode=True))
    farm = Farm({"devices": [{"name": "d", "address": "127.0.0.1", "model": str(profile)}]})
    accepted, refused = 0, []
    with farm.running_in_thread(), RawClient("127.0.0.1") as client:
        client.register()
        right = all(client.get(1, 1, a).data == v for a, v in (
            (1, struct.pack("<H", device.vendor_id)), (2, struct.pack("<H", device.device_type)),
            (3, struct.pack("<H", device.product_code)), (4, bytes(device.revision))))
        name = device.product_name[:32].encode("latin-1")
        right = right and client.get(1, 1, 7).data == bytes((len(name),)) + name
        right = right and all(client.get(4, i, 4).data == struct.pack("<H", s) for i, s in model["points"].items())
        serial = 0
        for entry in model["connections"]:
            owner = owner_entry = None
            if entry["kind"] == "listen only":
                owner_entry = next((e for e in model["connections"] if e["t_o"] == entry["t_o"] and e["kind"] in (
                    "exclusive owner", "input only") and e["t_o_multicast"]), None)
                if owner_entry is not None:
                    serial += 1
                    reply, owner = _open(client, _path(device, owner_entry), owner_entry, serial, True)
                    owner = owner if reply.general_status == 0 else None
            serial += 1
            multicast = entry["kind"] == "listen only" or not entry["t_o_point_to_point"]
            reply, triad = _open(client, _path(device, entry), entry, serial, multicast)
            if reply.general_status == 0:
                accepted += 1
                _close(client, triad, _path(device, entry))
            else:
                refused.append(f"{path.name} {entry['entry']}: 0x{reply.general_status:02X} "
                               f"{[hex(s) for s in reply.additional_status]}")
            if owner is not None:
                _close(client, owner, _path(device, owner_entry))
    return right, accepted, len(model["connections"]), refused


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", nargs="?", type=Path, default=Path(__file__).resolve().parent.parent / "tests"
                        / "data" / "eds")
    parser.add_argument("--copies", type=int, default=50, help="copies of the folder for the bulk import timing")
    parser.add_argument("--no-serve", action="store_true")
    args = parser.parse_args()
    imported, failed, times = import_all(args.folder)
    total = len(imported) + len(failed)
    print(f"import: {len(imported)} of {total} files; median {statistics.median(times) * 1e3:.1f} ms per file, "
          f"max {max(times) * 1e3:.1f} ms")
    for line in failed:
        print(f"  refused: {line}")
    started = time.perf_counter()
    for _ in range(args.copies):
        import_all(args.folder)
    print(f"import of {args.copies * total} files ({args.copies} copies): {time.perf_counter() - started:.1f} s")
    if args.no_serve:
        return
    right = accepted = entries = 0
    refusals: list[str] = []
    with tempfile.TemporaryDirectory() as workdir:
        for path, device, model in imported:
            ok, opened, declared, refused = serve_and_check(path, device, model, Path(workdir))
            right += ok
            accepted += opened
            entries += declared
            refusals += refused
    print(f"served: {right} of {total} files answer their identity and every assembly size; "
          f"{accepted} of {entries} class-1 connection entries accepted with their own path, sizes and RPI")
    for line in refusals:
        print(f"  refused: {line}")


if __name__ == "__main__":
    main()
