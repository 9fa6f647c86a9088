"""Rebuild captures/dsqc1030_explicit_session.pcap from captures/seed_session.yaml.

Frames 5 and 8 are the captured bytes; the others are built with dpkt and the project's codec
(captures/README.md says which bytes are reconstructed). Every frame length is checked against the
seed's table.

    python captures/build_seed_capture.py [OUTPUT]
"""

from __future__ import annotations

import socket
import struct
import sys
from pathlib import Path

import dpkt
import yaml

from enip_farm.protocol.commands import encode_send_rr_data
from enip_farm.protocol.encapsulation import Command, encode_frame

HERE = Path(__file__).resolve().parent
FLAGS = {"FIN": dpkt.tcp.TH_FIN, "SYN": dpkt.tcp.TH_SYN, "PSH": dpkt.tcp.TH_PUSH, "ACK": dpkt.tcp.TH_ACK}


def _mac(text: str) -> bytes:
    return bytes.fromhex(text.replace(":", ""))


def _payload(frame: dict) -> bytes:
    if "register_session" in frame:
        return encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00", frame["register_session"]["session"])
    if "send_rr_data" in frame:
        spec = frame["send_rr_data"]
        return encode_send_rr_data(bytes.fromhex(spec["cip"]), spec["session"])
    if "unregister_session" in frame:
        return encode_frame(Command.UNREGISTER_SESSION, session_handle=frame["unregister_session"]["session"])
    return b""


def build(data: dict) -> list[bytes]:
    client, device = data["client"], data["device"]
    captured = {number: bytes.fromhex(text) for number, text in data["captured"].items()}
    # sequence numbers continue from what the captured frames show
    syn_ack = dpkt.ethernet.Ethernet(captured[5]).data.data
    register_reply = dpkt.ethernet.Ethernet(captured[8]).data.data
    # the device's sequence numbers follow the captured SYN,ACK until frame 8, whose captured
    # bytes carry another sequence; from there on they follow frame 8
    seq = {"client": data["client_isn"], "device": (syn_ack.seq + 1) & 0xFFFFFFFF}
    ip_id = {"client": 0x1000, "device": 2}
    frames = []
    for frame in data["frames"]:
        if frame.get("captured"):
            raw = captured[frame["number"]]
            if frame["number"] == 5:
                seq["client"] = syn_ack.ack
        else:
            side = frame["from"]
            me, peer = (client, device) if side == "client" else (device, client)
            payload = _payload(frame)
            flags = 0
            for name in frame["flags"]:
                flags |= FLAGS[name]
            other = "device" if side == "client" else "client"
            if side == "client":
                options = b""
                if frame.get("tcp_options") == "mss1460-ws8-sackperm":
                    options = struct.pack(">BBH", 2, 4, 1460) + b"\x01\x03\x03\x08\x01\x01\x04\x02"
            else:
                options = struct.pack(">BBH", 2, 4, device["mss"])  # the device sends MSS on every segment
            tcp = dpkt.tcp.TCP(sport=me["port"], dport=peer["port"], seq=seq[side],
                               ack=seq[other] if flags & dpkt.tcp.TH_ACK else 0, flags=flags, win=me["window"],
                               opts=options, data=payload)
            tcp.off = (20 + len(options)) // 4
            ip = dpkt.ip.IP(src=socket.inet_aton(me["ip"]), dst=socket.inet_aton(peer["ip"]), p=dpkt.ip.IP_PROTO_TCP,
                            ttl=me["ttl"], id=ip_id[side], data=tcp)
            ip.len = len(ip)
            ip_id[side] += 1
            raw = bytes(dpkt.ethernet.Ethernet(src=_mac(me["mac"]), dst=_mac(peer["mac"]),
                                               type=dpkt.ethernet.ETH_TYPE_IP, data=ip))
            if side == "device" and len(raw) < 60:
                raw += bytes(60 - len(raw))  # received frames carry Ethernet padding; the PC's own do not
            seq[side] = (seq[side] + len(payload) + (1 if flags & (dpkt.tcp.TH_SYN | dpkt.tcp.TH_FIN) else 0)) \
                & 0xFFFFFFFF
        if frame["number"] == 8:
            seq["device"] = (register_reply.seq + len(register_reply.data)) & 0xFFFFFFFF
        if len(raw) != frame["length"]:
            raise ValueError(f"frame {frame['number']}: {len(raw)} bytes, the seed's table says {frame['length']}")
        frames.append(raw)
    return frames


def main() -> None:
    output = Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "dsqc1030_explicit_session.pcap"
    frames = build(yaml.safe_load((HERE / "seed_session.yaml").read_text()))
    with open(output, "wb") as handle:
        writer = dpkt.pcap.Writer(handle, linktype=dpkt.pcap.DLT_EN10MB)
        for index, raw in enumerate(frames):
            writer.writepkt(raw, ts=1.0 + index * 0.0002)
    print(f"{output}: {len(frames)} frames")


if __name__ == "__main__":
    main()
