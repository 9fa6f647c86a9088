"""Issue 32's survivors of a degraded link on one device's class-1 path (device/cyclic.py: a link
degraded one way only holds that way and passes the other) and of the device transaction's `watch`
(device/guard.py: images added to a transaction, a copy before taken once). Exact values on an
injected clock (`now`, ns), no sockets."""

from __future__ import annotations

from enip_farm.device.events import ImageChanged
from enip_farm.device.faults import Fault
from enip_farm.device.guard import INPUT_IMAGE, OUTPUT_IMAGE
from enip_farm.protocol.connection import decode_io_packet, encode_io_packet
from tests.test_pinned_details import PEER, T0, _dsqc1030
from tests.test_pinned_paths import MS, RUN, _open


def test_a_link_degraded_to_the_device_holds_the_o_t_and_passes_the_t_o() -> None:
    """`direction="to-device"`: the T->O goes out at once, the O->T reaches the outputs 5 ms late,
    not a tick before (mutants of `path.from_device is not None` in `receive_io` raised on the missing
    direction; of `path.to_device is not None` in `service_io` never delivered what was held)."""
    device = _dsqc1030()
    connection = _open(device)
    device.faults.set(Fault("degraded-link", delay_ms=5, direction="to-device"), T0)
    sent: list[tuple[bytes, tuple[str, int]]] = []
    assert device.service_io(T0, lambda packet, address: sent.append((packet, address))) == T0 + 10 * MS
    assert [(decode_io_packet(p).connection_id, a) for p, a in sent] == [(connection.t_o_id, (PEER, 2222))]
    zeros = bytes(len(device.outputs))
    one = b"\x01" + zeros[1:]
    packet = encode_io_packet(connection.o_t_id, 1, 1, RUN + one)
    assert device.receive_io(packet, (PEER, 2222), T0 + MS, sent.append, None) is True  # held: taken later
    assert device.outputs == zeros
    assert device.service_io(T0 + 6 * MS - 1, sent.append) == T0 + 6 * MS
    assert device.outputs == zeros
    assert device.service_io(T0 + 6 * MS, sent.append) == T0 + 10 * MS
    assert device.outputs == one and len(sent) == 1


def test_a_link_degraded_from_the_device_passes_the_o_t_and_holds_the_t_o() -> None:
    """`direction="from-device"`: the O->T reaches the outputs at once, the T->O goes out 5 ms late,
    not a tick before (mutants of `path.to_device is not None`, in `receive_io` and in `service_io`,
    raised on the missing direction)."""
    device = _dsqc1030()
    connection = _open(device)
    device.faults.set(Fault("degraded-link", delay_ms=5, direction="from-device"), T0)
    one = b"\x01" + bytes(len(device.outputs) - 1)
    packet = encode_io_packet(connection.o_t_id, 1, 1, RUN + one)
    sent: list[tuple[bytes, tuple[str, int]]] = []

    def send(packet: bytes, address: tuple[str, int]) -> None:
        sent.append((packet, address))

    assert device.receive_io(packet, (PEER, 2222), T0, send, None) is True
    assert device.outputs == one
    assert device.service_io(T0, send) == T0 + 5 * MS
    assert device.service_io(T0 + 5 * MS - 1, send) == T0 + 5 * MS
    assert sent == []
    assert device.service_io(T0 + 5 * MS, send) == T0 + 10 * MS
    assert [(decode_io_packet(p).connection_id, a) for p, a in sent] == [(connection.t_o_id, (PEER, 2222))]


def test_watch_adds_the_outputs_to_a_transaction_of_the_inputs() -> None:
    """`Transaction.watch(OUTPUT_IMAGE)` in a transaction that compares the inputs: the outputs are
    compared too (a mutant, `self.images * OUTPUT_IMAGE`, read the inputs' flag as the outputs')."""
    device, seen = _dsqc1030(), []
    device.observe(seen.append, ImageChanged)
    zeros = bytes(len(device.outputs))
    with device.guard.transaction(T0, INPUT_IMAGE) as transaction:
        transaction.watch(OUTPUT_IMAGE)
        device.guard.output.data[0] = 7
    assert [(e.monotonic_ns, e.detail) for e in seen] == [(T0, ImageChanged("output", zeros, b"\x07" + zeros[1:]))]


def test_watch_again_keeps_the_copy_taken_first() -> None:
    """Watching an image the transaction already compares takes no new copy: a change made in
    between is still told, from the bytes before the transaction (a mutant, `... or guard.output is
    not None`, copied the outputs again and lost it)."""
    device, seen = _dsqc1030(), []
    device.observe(seen.append, ImageChanged)
    zeros = bytes(len(device.outputs))
    with device.guard.transaction(T0, OUTPUT_IMAGE) as transaction:
        device.guard.output.data[0] = 7
        transaction.watch(OUTPUT_IMAGE)
    assert [(e.monotonic_ns, e.detail) for e in seen] == [(T0, ImageChanged("output", zeros, b"\x07" + zeros[1:]))]
