"""Multicast safe inputs (CIP Networks Library Vol. 5, 2-4.7 and 3-5.4; the checks and statuses of
the HMS CIP Safety target stack): originators from several hosts open the same safety input point
with T->O multicast and join one producer, each with its own consumer number; each one's time
coordination sets its own time correction section; one consumer leaving or timing out leaves the
others; the last one ends the production. Raw frames through the sans-IO connection table."""

from __future__ import annotations

import ipaddress
import shutil
import socket
import struct
import subprocess
from contextlib import ExitStack
from pathlib import Path

import pytest

from enip_farm.cip.admission import Originator
from enip_farm.cip.connection_events import ConnectionRefused, ConnectionTimedOut
from enip_farm.cip.connection_policy import Refusal
from enip_farm.cip.connection_table import ConnectionTable, Opened
from enip_farm.config import parse_config
from enip_farm.farm.farm import Farm
from enip_farm.protocol.cip import encode_request
from enip_farm.protocol.commands import decode_sockaddr
from enip_farm.protocol.connection import (
    ForwardCloseRequest,
    ForwardOpenRequest,
    class0_data,
    decode_forward_open_reply,
    decode_io_packet,
    encode_class0_packet,
    encode_forward_close,
    encode_forward_open,
)
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.safety.crc import Seeds
from enip_farm.protocol.safety.messages import (
    TimeCorrection,
    decode_data,
    decode_time_correction,
    encode_time_coordination,
    wire_size,
)
from enip_farm.protocol.safety.segment import Unid
from enip_farm.protocol.safety.validator import ticks
from enip_farm.protocol.status import ExtendedStatus as X
from tests.helpers import RawClient
from tests.test_safety import MS, SERIAL, T0, VENDOR, _pid, make_table, safety_open

GROUP = ("239.192.1.0", 2222)
NULL = TimeCorrection(0, False, 0)
HOSTS = [f"127.0.1.{n}" for n in range(1, 17)]


def multicast_open(max_consumers: int = 3, **kwargs: object) -> ForwardOpenRequest:
    return safety_open(server=False, multicast=True, max_consumer_number=max_consumers, **kwargs)  # type: ignore[arg-type]


def open_from(table: ConnectionTable, host: str, request: ForwardOpenRequest, now: int = T0) -> Opened:
    result = table.forward_open(request, Originator(host), now)
    assert type(result) is Opened, result
    return result


def reply_fields(opened: Opened) -> tuple[int, int, int, int]:
    """Consumer number, target vendor id, serial number, connection serial number (instance)."""
    return struct.unpack_from("<HHIH", opened.application_reply)  # type: ignore[return-value]


def answer(table: ConnectionTable, host: str, opened: Opened, request: ForwardOpenRequest, ping: int, time: int,
           now: int, sequence: int = 1, extended: bool = False) -> bool:
    message = encode_time_coordination(ping, time, _pid(request), extended)
    return table.receive_datagram(encode_class0_packet(opened.connection.o_t_id, sequence, message), host, now, 2222)


def produced(table: ConnectionTable, now: int, pid: Seeds, extended: bool = False,
             rollover: int = 0) -> tuple[object, TimeCorrection | None]:
    """The one T->O packet due at `now`, sent to the group: its data message and time correction."""
    (packet, address), = table.datagrams_to_send(now)
    assert address == GROUP
    io = decode_io_packet(packet)
    assert io is not None
    message = class0_data(io)
    size = wire_size(2)
    assert len(message) == size + 6
    data = decode_data(message[:size], 2, pid, extended, rollover)
    return data, decode_time_correction(message[size:], pid, extended)


def test_three_originators_join_one_producer_each_with_its_own_consumer_number() -> None:
    table = make_table()
    table.assemblies["input"].data[:] = b"\x04\x08"
    requests = [multicast_open() for _ in range(3)]
    opened = [open_from(table, host, request) for host, request in zip(HOSTS, requests, strict=False)]
    (instance,) = {reply_fields(o)[3] for o in opened}
    assert [reply_fields(o) for o in opened] == [(n, VENDOR, SERIAL, instance) for n in (1, 2, 3)]
    (t_o_id,) = {o.connection.t_o_id for o in opened}
    assert t_o_id not in {r.t_o_connection_id for r in requests}  # the target picks a multicast T->O id
    for o in opened:
        (item,) = o.reply_items
        assert item[0] == ItemType.SOCKADDR_T_O and decode_sockaddr(item[1])[:2] == GROUP
        assert o.connection.multicast and o.connection.t_o_address == GROUP
    (production,) = table.productions.values()
    assert production.users == 3 and len(table.connections) == 3
    pid = Seeds.of(VENDOR, SERIAL, instance)
    data, section = produced(table, T0, pid)
    assert data is not None and data.data == b"\x04\x08" and data.timestamp == ticks(T0) and data.ping_count == 0
    assert section == NULL  # nobody answered yet
    # each consumer answers ping 0 with its own time: the producer's clock + 1000 x its number
    at = T0 + 3 * MS
    for number, (host, o, request) in enumerate(zip(HOSTS, opened, requests, strict=False), 1):
        assert answer(table, host, o, request, 0, ticks(at) + 1000 * number, at)
    assert table.counters["safety_packets_consumed"] == 3
    sections = [produced(table, T0 + n * 10 * MS, pid)[1] for n in range(1, 12)]
    # from the 8th production of the ping interval, once round the consumer numbers, then null sections
    assert sections == [NULL] * 6 + [TimeCorrection(n, True, 1000 * n) for n in (1, 2, 3)] + [NULL] * 2


def test_a_time_coordination_of_another_ping_or_crc_leaves_a_consumer_idle() -> None:
    table = make_table()
    first, second = multicast_open(), multicast_open()
    one, two = open_from(table, HOSTS[0], first), open_from(table, HOSTS[1], second)
    pid = Seeds.of(VENDOR, SERIAL, reply_fields(one)[3])
    assert answer(table, HOSTS[0], one, first, 1, 500, T0)  # ping 1 is not the current ping: no correction
    assert not answer(table, HOSTS[1], two, first, 0, 500, T0)  # another consumer's CID seed: a CRC fault
    assert table.counters["safety_crc_faults"] == 1 and len(table.connections) == 2
    assert [produced(table, T0 + n * 10 * MS, pid)[1] for n in range(10)] == [NULL] * 10


def test_a_close_or_a_timeout_removes_only_that_consumer_and_the_last_ends_the_production() -> None:
    table = make_table(first_watchdog_ms=0)
    requests = [multicast_open(ping=100, timeout_multiplier=2) for _ in range(3)]  # ping interval 1 s
    opened = [open_from(table, host, request) for host, request in zip(HOSTS, requests, strict=False)]
    pid = Seeds.of(VENDOR, SERIAL, reply_fields(opened[0])[3])
    table.datagrams_to_send(T0)
    for number, (host, o, request) in enumerate(zip(HOSTS, opened, requests, strict=False), 1):
        assert answer(table, host, o, request, 0, 0, T0 + number * MS)
    assert table.forward_close(requests[1].triad, T0 + 2 * MS, HOSTS[1]) is opened[1].connection
    assert len(table.connections) == 2 and next(iter(table.productions.values())).users == 2
    sections = [produced(table, T0 + n * 10 * MS, pid)[1] for n in range(1, 11)]
    assert [s.consumer_number for s in sections if s != NULL] == [1, 3]  # type: ignore[union-attr]
    # a fourth originator takes the free number 2
    fourth = multicast_open(ping=100, timeout_multiplier=2)
    assert reply_fields(open_from(table, HOSTS[3], fourth, T0 + 110 * MS))[0] == 2
    # consumer 1 times out alone, (2 + 2) ping intervals after its last answer
    deadline = T0 + MS + 4 * 1000 * MS
    assert opened[0].connection.deadline == deadline
    table.handle_timer(deadline - 1)
    assert len(table.connections) == 3
    table.handle_timer(deadline)
    assert opened[0].connection.closed and not opened[2].connection.closed and len(table.connections) == 2
    assert [e.reason for e in table.pop_events() if type(e) is ConnectionTimedOut] == [
        "safety timeout: no time coordination for 4 ping intervals"]
    assert table.productions  # the others still consume
    for request, host in ((requests[2], HOSTS[2]), (fourth, HOSTS[3])):
        table.forward_close(request.triad, deadline + MS, host)
    assert not table.connections and not table.productions


def test_the_sixteenth_consumer_is_refused_resource_unavailable() -> None:
    table = make_table()  # 8 Safety Validator instances: the consumers of one producer share one
    opened = [open_from(table, host, multicast_open(max_consumers=15)) for host in HOSTS[:15]]
    assert [reply_fields(o)[0] for o in opened] == list(range(1, 16))
    refused = table.forward_open(multicast_open(max_consumers=15), Originator(HOSTS[15]), T0)
    assert refused == Refusal(None, general=0x02) and refused.additional_status == ()  # type: ignore[union-attr]
    events = [e.reason for e in table.pop_events() if type(e) is ConnectionRefused]
    (reason,) = events
    assert reason.startswith(f"Forward Open from {HOSTS[15]}: 0x02 resource unavailable (class 0, O->T RPI 10000 us"
                             " 6 bytes, T->O RPI 10000 us 14 bytes, path 20 04 24 01 2c 00 2c 65 50 1b ")


def test_extended_format_multicast_the_producer_picks_the_initial_timestamp_and_rollover() -> None:
    table = make_table()
    table.assemblies["input"].data[:] = b"\x01\x02"
    first = multicast_open(extended=True, initial_timestamp=0xFFFF, initial_rollover_value=0xFFFF)
    one = open_from(table, HOSTS[0], first)
    number, _, _, instance, initial_ts, initial_rv = struct.unpack("<HHIHHH", one.application_reply)
    assert (number, initial_ts, initial_rv) == (1, ticks(T0), 0)
    pid = Seeds.of(VENDOR, SERIAL, instance)
    assert answer(table, HOSTS[0], one, first, 0, ticks(T0) + 77, T0, extended=True)
    later = T0 + 5 * MS
    two = open_from(table, HOSTS[1], multicast_open(extended=True, initial_timestamp=0xFFFF,
                                                   initial_rollover_value=0xFFFF), later)
    assert struct.unpack("<HHIHHH", two.application_reply)[4:] == (ticks(T0), 0)  # where the producer stands
    sections = []
    for n in range(1, 9):
        data, section = produced(table, T0 + n * 10 * MS, pid, extended=True)
        assert data is not None and data.data == b"\x01\x02" and data.run
        sections.append(section)
    assert sections == [NULL] * 7 + [TimeCorrection(1, True, 77)]


def _refusal(request: ForwardOpenRequest, table: ConnectionTable | None = None) -> tuple[int, ...]:
    result = (table or make_table()).forward_open(request, Originator(HOSTS[9]), T0)
    assert type(result) is Refusal, result
    return (result.general, *result.additional_status)


@pytest.mark.parametrize(("request_kwargs", "status"), [
    ({"server": True, "max_consumer_number": 2}, (0x01, X.INVALID_MAX_CONSUMER_NUMBER)),  # safe outputs: one
    ({"server": False, "max_consumer_number": 2}, (0x01, X.INVALID_MAX_CONSUMER_NUMBER)),  # single-cast inputs
    ({"server": False, "multicast": True, "max_consumer_number": 16}, (0x01, X.INVALID_MAX_CONSUMER_NUMBER)),
    ({"server": False, "multicast": True, "max_consumer_number": 0}, (0x01, X.INVALID_MAX_CONSUMER_NUMBER)),
    ({"server": False, "multicast": True, "max_consumer_number": 2, "time_correction_parameters": 0x4806},
     (0x01, X.INVALID_TIME_CORRECTION_PARAMETERS)),  # a separate time correction connection: not built
    ({"server": False, "multicast": True, "max_consumer_number": 2, "data_size": 8},
     (0x01, X.INVALID_SAFETY_CONNECTION_SIZE)),  # no room for the time correction
    ({"server": False, "multicast": True, "max_consumer_number": 2, "data_size": 13},
     (0x01, X.INVALID_T_O_SIZE, 14)),
    ({"server": False, "multicast": True, "max_consumer_number": 2, "extended": True, "initial_timestamp": 5},
     (0x01, X.PARAMETER_ERROR)),  # the multicast producer picks the initial values
    ({"server": False, "multicast": True, "max_consumer_number": 15, "ping": 44},
     (0x01, X.INVALID_PING_INTERVAL_EPI_MULTIPLIER)),  # at least min(2, 4) x 15 + 15
])
def test_multicast_safety_open_refusals(request_kwargs: dict, status: tuple[int, ...]) -> None:
    assert _refusal(safety_open(**request_kwargs)) == status


def test_a_multicast_time_correction_epi_and_connection_id_are_not_checked() -> None:
    table = make_table()
    open_from(table, HOSTS[0], multicast_open(time_correction_epi=10_000, time_correction_connection_id=7))
    assert _refusal(safety_open(server=False, time_correction_connection_id=7)) == (
        0x01, X.INVALID_TIME_CORRECTION_CONNECTION_ID)  # single-cast: 0xFFFFFFFF only


@pytest.mark.parametrize(("join_kwargs", "status"), [
    ({"ping": 101}, (0x01, X.MULTICAST_PING_INTERVAL_EPI_MULTIPLIER)),
    ({"max_consumers": 4}, (0x01, X.MULTICAST_MAX_CONSUMER_NUMBER)),
    ({"extended": True, "initial_timestamp": 0xFFFF, "initial_rollover_value": 0xFFFF},
     (0x01, X.MULTICAST_SAFETY_FORMAT)),
    ({"rpi_us": 20_000}, (0x01, X.RPI_NOT_ACCEPTABLE, 0x0404, 10_000, 0, 10_000, 0)),  # required: the producer's
])
def test_a_join_must_ask_for_what_the_producer_produces(join_kwargs: dict, status: tuple[int, ...]) -> None:
    table = make_table()
    open_from(table, HOSTS[0], multicast_open())
    assert _refusal(multicast_open(**join_kwargs), table) == status
    assert len(table.connections) == 1 and next(iter(table.productions.values())).users == 1


# -- on the wire: three originators of their own, the farm's multicast, Wireshark on the recording ----------


def _multicast_receiver(group: str) -> socket.socket:
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    receiver.bind(("0.0.0.0", 2222))  # beside the farm's device sockets, as a scanner binds
    receiver.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                        socket.inet_aton(group) + socket.inet_aton("127.0.0.1"))
    receiver.settimeout(5)
    return receiver


@pytest.mark.system
@pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark (Debian) is not installed; .ci/run installs it")
def test_three_originators_consume_the_farms_multicast_safe_inputs(free_address, tmp_path: Path) -> None:
    address = free_address()
    hosts = [free_address() for _ in range(3)]
    recording = tmp_path / "multicast.pcap"
    farm = Farm(parse_config({"devices": [{"name": "s", "address": address, "model": "DSQC1042"}],
                              "discovery": False}), record=recording)
    tunid = Unid(bytes.fromhex("000000000001"), int(ipaddress.IPv4Address(address)))
    requests = [multicast_open(tunid=tunid, ping=50) for _ in hosts]  # ping interval 500 ms, timeout 2 s
    with ExitStack() as stack:
        stack.enter_context(farm.running_in_thread())
        clients = [stack.enter_context(RawClient(address, source=host)) for host in hosts]
        senders = []
        for host in hosts:
            sender = stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
            sender.bind((host, 0))
            senders.append(sender)
        replies = []
        for client, request in zip(clients, requests, strict=True):
            client.register()
            reply, items = client.request_items(encode_request(0x54, encode_request_path(6, 1),
                                                               encode_forward_open(request)))
            assert reply.general_status == 0, reply
            replies.append((decode_forward_open_reply(reply.data), items))
        (t_o_id,) = {opened.t_o_connection_id for opened, _ in replies}
        (group,) = {decode_sockaddr(items[0].data).host for _, items in replies}
        numbers = [struct.unpack_from("<H", opened.application_reply)[0] for opened, _ in replies]
        assert numbers == [1, 2, 3]
        (instance,) = {struct.unpack_from("<H", opened.application_reply, 8)[0] for opened, _ in replies}
        pid = Seeds.of(75, farm.device("s").profile.serial_number, instance)
        validator_type = clients[0].get(0x3A, instance, 2)
        assert validator_type.general_status == 0 and validator_type.data == b"\x02"  # producer, multicast
        farm["s"].set(DI1=1, DI12=1)  # before joining: every message the receivers get carries it
        receivers = [stack.enter_context(_multicast_receiver(group)) for _ in hosts]

        sequence = iter(range(1, 1_000_000))
        last_ping: list[int | None] = [None]

        def sections(receiver: socket.socket, consumers: list[int], until: set[int]) -> set[int]:
            """Answer every ping of `consumers` (indices), read the multicast until the active time
            correction sections of the numbers `until` were seen: the numbers seen."""
            seen: set[int] = set()
            while not until <= seen:
                io = decode_io_packet(receiver.recv(2048))
                if io is None or io.connection_id != t_o_id:
                    continue  # another test's multicast on port 2222
                message = class0_data(io)
                data = decode_data(message[:8], 2, pid, False)
                section = decode_time_correction(message[8:], pid, False)
                assert data is not None and section is not None and data.data == b"\x01\x08"
                if data.ping_count != last_ping[0]:
                    last_ping[0] = data.ping_count
                    for k in consumers:  # each answers with its own time: the producer's + 10000 x number
                        message = encode_time_coordination(data.ping_count, data.timestamp + 10_000 * (k + 1),
                                                           _pid(requests[k]), False)
                        senders[k].sendto(encode_class0_packet(replies[k][0].o_t_connection_id, next(sequence),
                                                               message), (address, 2222))
                if section.active:
                    # its correction: its time value minus the farm's clock when the answer came
                    assert 0 <= 10_000 * section.consumer_number - section.value < 5_000
                    seen.add(section.consumer_number)
            return seen

        assert sections(receivers[0], [0, 1, 2], {1, 2, 3}) == {1, 2, 3}
        for receiver in receivers[1:]:  # every originator's socket gets the stream
            io = decode_io_packet(receiver.recv(2048))
            while io is None or io.connection_id != t_o_id:
                io = decode_io_packet(receiver.recv(2048))
        close = clients[1].request(encode_request(0x4E, encode_request_path(6, 1), encode_forward_close(
            ForwardCloseRequest(0x05, 0x9C, requests[1].triad, requests[1].connection_path))))
        assert close.general_status == 0
        last_ping[0] = None
        after = stack.enter_context(_multicast_receiver(group))  # what the farm sends from the close on
        assert sections(after, [0, 2], {1, 3}) == {1, 3}  # 2 is gone, 1 and 3 go on
        assert len(farm.device("s").connections) == 2
    expert = subprocess.run(["tshark", "-r", str(recording), "-q", "-z", "expert"], capture_output=True, text=True,
                            timeout=120)
    assert expert.returncode == 0, expert.stderr
    assert "Errors (" not in expert.stdout and "Warnings (" not in expert.stdout, expert.stdout
    fields = subprocess.run(["tshark", "-r", str(recording), "-Y", f"cipsafety && ip.dst == {group}", "-T", "fields",
                             "-e", "cipsafety.mcast_byte.consumer_num", "-e", "cipsafety.mcast_byte.active_idle",
                             "-e", "cipsafety.crc_s1.status", "-e", "cipsafety.crc_s2.status"],
                            capture_output=True, text=True, timeout=120).stdout.splitlines()
    rows = {tuple(line.split("\t")) for line in fields}
    # Wireshark reads the multicast data messages with their time correction sections; every CRC good (1)
    assert {row[0] for row in rows if row[1] in ("1", "True")} == {"0x01", "0x02", "0x03"}, rows
    assert {row[2:] for row in rows} == {("1,1", "1")}, rows  # CRC-S1 of the data and of the timestamp, CRC-S2
    replies = subprocess.run(["tshark", "-r", str(recording), "-Y", "cip.cm.app_reply_size == 5", "-V"],
                             capture_output=True, text=True, timeout=120).stdout
    assert [line.strip() for line in replies.splitlines() if "Consumer Number:" in line] == [
        "Consumer Number: 1", "Consumer Number: 2", "Consumer Number: 3"]
