"""Identity Reset timing: how soon after its Reset reply a device's TCP connection ends, and how late
after its reset time it takes connections again.

Starts `python -m enip_farm serve` (one DSQC1030, `reset_time_s` as given) and, --resets times: a
raw client registers a session, sends Reset (type 0) and times the reply, the end of its connection
(EOF) and the first TCP connect that succeeds (tried every --poll-ms), counting the refused ones.
Prints p50 / p99 / max of each. Every loop is bounded in count and time. Loopback only.

    python bench/bench_reset.py [--resets 20] [--reset-time 0.2] [--poll-ms 1]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from enip_client import PORT, recv_exact, register

from enip_farm.protocol.commands import encode_send_rr_data

HOST = "127.0.201.1"
RESET = bytes.fromhex("05 02 20 01 24 01")
RESET_REPLY_SIZE = 24 + 16 + 4


def wait_listening(timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection((HOST, PORT), timeout=1).close()
            return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError("the farm did not listen in time")


def one_reset(reset_time: float, poll_s: float) -> dict[str, float]:
    sock, handle = register(HOST)
    sent = time.monotonic()
    sock.sendall(encode_send_rr_data(RESET, handle))
    reply = recv_exact(sock, RESET_REPLY_SIZE)
    replied = time.monotonic()
    assert reply[-4:] == b"\x85\x00\x00\x00", reply.hex()
    sock.settimeout(5)
    assert sock.recv(1) == b"", "the connection did not end"
    ended = time.monotonic()
    sock.close()
    refused = 0
    deadline = sent + reset_time + 10
    while time.monotonic() < deadline:
        try:
            socket.create_connection((HOST, PORT), timeout=1).close()
            break
        except ConnectionRefusedError:
            refused += 1
            time.sleep(poll_s)
    else:
        raise TimeoutError("the device did not answer again")
    up = time.monotonic()
    return {"reply_ms": (replied - sent) * 1e3, "eof_after_reply_ms": (ended - replied) * 1e3,
            "answering_late_ms": (up - sent - reset_time) * 1e3, "refused": refused}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--resets", type=int, default=20)
    parser.add_argument("--reset-time", type=float, default=0.2)
    parser.add_argument("--poll-ms", type=float, default=1.0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "reset.yaml"
        config.write_text(json.dumps({"devices": [{"name": "io1", "address": HOST, "model": "DSQC1030",
                                                   "reset_time_s": args.reset_time}], "discovery": False}))
        farm = subprocess.Popen([sys.executable, "-m", "enip_farm", "serve", "--config", str(config)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=os.environ.copy())
        try:
            wait_listening()
            runs = [one_reset(args.reset_time, args.poll_ms / 1e3) for _ in range(args.resets)]
        finally:
            farm.terminate()
            farm.wait(30)
    print(f"{args.resets} resets, reset_time_s {args.reset_time}, connect tried every {args.poll_ms} ms")
    summary = {}
    for key in ("reply_ms", "eof_after_reply_ms", "answering_late_ms"):
        values = sorted(run[key] for run in runs)
        p99 = values[min(len(values) - 1, round(0.99 * (len(values) - 1)))]
        summary[key] = {"p50": statistics.median(values), "p99": p99, "min": values[0], "max": values[-1]}
        print(f"  {key:20s} p50 {summary[key]['p50']:8.3f}  p99 {p99:8.3f}  min {values[0]:8.3f}"
              f"  max {values[-1]:8.3f}")
    print(f"  refused connects per reset: {statistics.median(run['refused'] for run in runs):g} (median)")
    if args.json:
        args.json.write_text(json.dumps({"runs": runs, "summary": summary}))


if __name__ == "__main__":
    main()
