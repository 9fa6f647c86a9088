"""The HTTP API against hostile or careless clients: fault parameters range-checked (422 naming the
field, the same checks for the Python API), all-or-nothing image writes, a body-size limit, the
Host header against DNS rebinding, the token on every path, and the event stream's bounded queues,
subscriber cap and stalled readers. Everything talks to the real server on loopback."""

from __future__ import annotations

import json
import math
import socket
import time

import httpx
import pytest

from enip_farm.config import parse_config
from enip_farm.control.guard import MAX_BODY, allowed_hosts, host_name
from enip_farm.device.events import TcpConnected
from enip_farm.device.faults import MAX_DELAY_MS, Fault, FaultError
from enip_farm.pytest_plugin import AddressPool
from tests.helpers import wait_for

DEADLINE_S = 30.0  # generous: conditions end the waits as soon as they hold


def raw(port: int, request: bytes, host: str = "127.0.0.1", rcvbuf: int | None = None) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if rcvbuf is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.settimeout(DEADLINE_S)
    sock.connect((host, port))
    sock.sendall(request)
    return sock


def read_until(sock: socket.socket, marker: bytes, limit: int = 1 << 20) -> bytes:
    data = b""
    while marker not in data:
        chunk = sock.recv(65536)
        if not chunk or len(data) > limit:
            break
        data += chunk
    return data


def read_all(sock: socket.socket) -> bytes:
    data = b""
    while chunk := sock.recv(65536):
        data += chunk
    return data


# -- fault parameters ----------------------------------------------------------------------------------

BAD_FAULTS = [
    ('{"kind": "delay", "delay_ms": Infinity}', "delay_ms"),
    ('{"kind": "delay", "delay_ms": NaN}', "delay_ms"),
    ('{"kind": "delay", "delay_ms": 1e999}', "delay_ms"),
    ('{"kind": "delay", "delay_ms": -1}', "delay_ms"),
    ('{"kind": "delay", "delay_ms": 60001}', "delay_ms"),
    ('{"kind": "delay", "delay_ms": 10, "max_delay_ms": 5}', "max_delay_ms"),
    ('{"kind": "delay", "max_delay_ms": -Infinity}', "max_delay_ms"),
    ('{"kind": "status", "service": 14, "status": 300}', "status"),
    ('{"kind": "status", "service": 256, "status": 8}', "service"),
    ('{"kind": "status", "service": -1, "status": 8}', "service"),
    ('{"kind": "status", "service": 14}', "status"),
    ('{"kind": "drop", "duration_s": 0}', "duration_s"),
    ('{"kind": "drop", "duration_s": NaN}', "duration_s"),
    ('{"kind": "drop", "duration_s": -5}', "duration_s"),
    ('{"kind": "sideways"}', "kind"),
]


def test_fault_parameters_are_checked_in_one_place() -> None:
    for body, field in BAD_FAULTS:
        with pytest.raises(FaultError) as refused:
            Fault(**json.loads(body))
        assert refused.value.field == field and str(refused.value).startswith(f"{field}: "), body
    with pytest.raises(FaultError, match=r"^service: must be a CIP service code 0\.\.255 \(0x00\.\.0xFF\), got True$"):
        Fault("status", service=True, status=8)
    with pytest.raises(FaultError, match="^delay_ms: must be a number, got '5'$"):
        Fault("delay", delay_ms="5")
    with pytest.raises(FaultError, match="^delay_ms: must be a number, got None$"):  # the page's NaN, as JSON
        Fault("delay", delay_ms=None)
    assert Fault("delay", delay_ms=MAX_DELAY_MS).on_reply() == 60_000_000_000
    assert Fault("status", service=0, status=0xFF).status == 0xFF


def test_bad_fault_parameters_get_422_naming_the_field(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    url = f"http://127.0.0.1:{farm.http.port}/devices/io/faults"
    for body, field in BAD_FAULTS:
        response = httpx.post(url, content=body, headers={"Content-Type": "application/json"})
        assert response.status_code == 422, (body, response.text)
        (error,) = response.json()["detail"]
        assert error["loc"] == ["body", field], (body, error)  # pydantic's own (kind) or Fault's, alike
    assert farm["io"].faults == []  # nothing was injected
    assert httpx.post(url, json={"kind": "status", "service": 0x0E, "status": 0xFF}).status_code == 201
    assert farm["io"].faults[0]["status"] == 0xFF


def test_python_api_refuses_the_same_parameters(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    with pytest.raises(ValueError, match="^delay_ms: must be finite, got inf$"):
        io.inject("delay", delay_ms=math.inf)
    with pytest.raises(ValueError, match=r"^status: must be a CIP general status 0\.\.255 \(0x00\.\.0xFF\), got 300$"):
        io.inject("status", service=0x0E, status=300)
    with pytest.raises(ValueError, match="^duration_s: must be > 0, got 0$"):
        io.inject("offline", duration_s=0)
    assert io.faults == []


def test_the_fault_kinds_are_listed_with_their_parameters(enip_farm) -> None:
    """GET /fault-kinds: the registry (device/fault_kinds.py) in order, each kind with a one-line
    summary and its parameters' JSON Schema; the OpenAPI schema names the answer's model."""
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    base = f"http://127.0.0.1:{farm.http.port}"
    kinds = httpx.get(f"{base}/fault-kinds").json()
    assert [kind["kind"] for kind in kinds] == ["delay", "drop", "close", "reset", "offline", "status", "stop-io",
                                                "identity", "power-loss", "link-down", "flapping-link",
                                                "degraded-link", "address-conflict", "wrong-module", "safety-crc",
                                                "safety-stale", "safety-time-coordination"]
    assert all(set(kind) == {"kind", "summary", "parameters"} for kind in kinds)
    assert all(kind["summary"] and "\n" not in kind["summary"] for kind in kinds)
    schemas = {kind["kind"]: kind["parameters"] for kind in kinds}
    assert {name: sorted(schema["properties"]) for name, schema in schemas.items()} == {
        "delay": ["delay_ms", "duration_s", "max_delay_ms"], "drop": ["duration_s"], "close": ["duration_s"],
        "reset": ["duration_s"], "offline": ["duration_s"], "status": ["duration_s", "service", "status"],
        "stop-io": ["duration_s"], "identity": ["duration_s"],
        "power-loss": ["boot_time_s", "duration_s", "self_test_s"],
        "link-down": ["duration_s"], "address-conflict": ["duration_s", "phase", "remote_mac"],
        "flapping-link": ["count", "duration_s", "duty", "max_s", "min_s", "period_s", "random", "seed"],
        "wrong-module": ["duration_s", "input_size", "major_revision", "minor_revision", "output_size", "product_code"],
        "safety-crc": ["duration_s"], "safety-stale": ["duration_s"], "safety-time-coordination": ["duration_s"],
        "degraded-link": ["delay_ms", "direction", "duplicate", "duration_s", "jitter_ms", "loss", "reorder",
                          "reorder_ms", "seed"]}
    assert schemas["status"]["required"] == ["service", "status"]
    assert schemas["status"]["properties"]["service"]["anyOf"][0] == {"type": "integer", "minimum": 0, "maximum": 255}
    assert schemas["delay"]["properties"]["delay_ms"]["maximum"] == MAX_DELAY_MS
    assert all(schema["type"] == "object" and schema["additionalProperties"] is False for schema in schemas.values())
    openapi = httpx.get(f"{base}/openapi.json").json()
    answer = openapi["paths"]["/fault-kinds"]["get"]["responses"]["200"]["content"]["application/json"]["schema"]
    assert answer["items"] == {"$ref": "#/components/schemas/FaultKindInfo"}
    assert sorted(openapi["components"]["schemas"]["FaultKindInfo"]["properties"]) == ["kind", "parameters", "summary"]


def test_a_parameter_no_kind_takes_is_refused_and_another_kinds_is_ignored() -> None:
    with pytest.raises(FaultError, match=r"^delay_msec: is not a parameter of any fault kind \(.*delay_ms, "):
        Fault("delay", delay_msec=800)
    assert Fault("drop", delay_ms=0.0, service=None).parameters() == {"kind": "drop"}  # what the CLI sends
    assert Fault("close", duration_s=2).duration_ns == 2_000_000_000


# -- all-or-nothing writes ---------------------------------------------------------------------------------


def test_a_refused_write_writes_nothing(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", addons=["DSQC1032"], http=True)
    io = farm["io"]
    url = f"http://127.0.0.1:{farm.http.port}/devices/io/io"
    io.set(DI2=1, DO2=1, AI1=7)
    before = io.inputs, io.outputs
    refused = [
        ({"signals": {"DI1": 1, "DO1": 1, "AI2": 40000}}, "AI2: 40000 does not fit an INT"),  # the last one
        ({"signals": {"DO1": 1, "AO1": 5, "DI99": 1}}, "DI99: this device has 16 DI signals"),
        ({"signals": {"DI1": 2}}, "DI1: a digital signal is 0 or 1, got 2"),
        ({"signals": {"DI1-4": [1, 1]}}, "DI1-4: 4 values expected, got 2"),
        ({"inputs": "00" * len(before[0]), "outputs": "zz"},
         "outputs: non-hexadecimal number found in fromhex() arg at position 0"),
        ({"outputs": "00" * len(before[1]), "inputs": "00"}, "inputs: the image is 10 bytes, got 1"),
    ]
    for body, detail in refused:
        response = httpx.put(url, json=body)
        assert response.status_code == 422 and response.json() == {"detail": detail}, (body, response.text)
        assert (io.inputs, io.outputs) == before, body
    with pytest.raises(ValueError, match="^AO1: 1048576 does not fit an INT$"):
        io.set(DI1=1, DO1=1, AO1=1 << 20)
    assert (io.inputs, io.outputs) == before
    both = httpx.put(url, json={"signals": {"DI1": 1, "DO1": 1, "AO1": -5}}).json()
    signals = both["signals"]
    assert signals["DI"][:2] == [1, 1] and signals["DO"][:2] == [1, 1] and signals["AO"][0] == -5


# -- the guard: body size, Host, token ----------------------------------------------------------------------


def test_body_size_limit(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    port = farm.http.port
    head = b"PUT /devices/io/io HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
    # a declared 100 MiB body is refused before any of it is sent
    with raw(port, head + b"Content-Length: %d\r\n\r\n" % (100 << 20)) as sock:
        reply = read_all(sock)
    assert reply.startswith(b"HTTP/1.1 413 ") and b"over 1048576 bytes" in reply
    # a chunked body is refused as soon as it passes the limit
    chunk = b"%x\r\n%s\r\n" % (65536, b" " * 65536)
    with raw(port, head + b"Transfer-Encoding: chunked\r\n\r\n" + chunk * (MAX_BODY // 65536 + 1)) as sock:
        reply = read_until(sock, b"\r\n\r\n")
    assert reply.startswith(b"HTTP/1.1 413 "), reply[:200]
    # a body within the limit is read whole
    padded = json.dumps({"signals": {"DI1": 1}}).encode().ljust(MAX_BODY - 10)
    response = httpx.put(f"http://127.0.0.1:{port}/devices/io/io", content=padded,
                         headers={"Content-Type": "application/json"})
    assert response.status_code == 200 and farm["io"].get("DI1") == 1


def test_host_names() -> None:
    assert host_name("LocalHost.:8044") == "localhost" and host_name("[::1]:80") == "::1"
    assert host_name("127.0.0.1") == "127.0.0.1" and host_name("evil.example:8044") == "evil.example"
    assert allowed_hosts("127.0.0.1") == {"127.0.0.1", "localhost", "::1"}
    assert allowed_hosts("127.0.9.9") == {"127.0.9.9", "127.0.0.1", "localhost", "::1"}
    assert allowed_hosts("192.0.2.7") == {"192.0.2.7"}
    assert allowed_hosts("0.0.0.0") is None and allowed_hosts("::") is None


def test_host_header_must_name_the_api(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    url = f"http://127.0.0.1:{farm.http.port}/devices"
    for host in ("localhost", f"localhost:{farm.http.port}", "127.0.0.1", f"[::1]:{farm.http.port}"):
        assert httpx.get(url, headers={"Host": host}).status_code == 200, host
    for host in ("rebound.example", f"rebound.example:{farm.http.port}", "127.0.0.1.evil.example"):
        response = httpx.get(url, headers={"Host": host})
        assert response.status_code == 421 and response.json() == {
            "detail": f"Host {host!r} is not this API's address (127.0.0.1 or ::1 or localhost)"}, host


@pytest.mark.integration
def test_token_guards_every_path_and_any_scheme_case(free_address: AddressPool) -> None:
    from enip_farm.farm.farm import Farm

    config = parse_config({"devices": [{"name": "io", "address": free_address(), "model": "DSQC1030"}],
                           "discovery": False})
    host = free_address()
    farm = Farm(config, http=(host, 0), token="s3cret")
    with farm.running_in_thread():
        base = f"http://{host}:{farm.http.port}"
        for path in ("/docs", "/openapi.json", "/redoc", "/devices", "/no/such/path"):
            response = httpx.get(base + path)
            assert response.status_code == 401 and response.headers["www-authenticate"] == "Bearer", path
        for scheme in ("Bearer", "bearer", "BEARER"):
            assert httpx.get(base + "/openapi.json", headers={"Authorization": f"{scheme} s3cret"}).status_code == 200
        assert httpx.get(base + "/docs", headers={"Authorization": "bearer s3cret"}).status_code == 200
        for wrong in ("Bearer s3cre", "Basic s3cret", "s3cret", "Bearer"):
            assert httpx.get(base + "/devices", headers={"Authorization": wrong}).status_code == 401, wrong
        # the Host check comes first, and holds with a token too
        assert httpx.get(base + "/devices", headers={"Host": "rebound.example",
                                                     "Authorization": "Bearer s3cret"}).status_code == 421


# -- the event stream ----------------------------------------------------------------------------------------


def _subscribe(port: int, query: str = "", rcvbuf: int | None = None) -> socket.socket:
    sock = raw(port, f"GET /events{query} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode(), rcvbuf=rcvbuf)
    head = read_until(sock, b"enip-farm event stream")
    assert head.startswith(b"HTTP/1.1 200 "), head
    return sock


def test_subscriber_cap_and_a_freed_slot(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    hub, port = farm.http.hub, farm.http.port
    hub.max_subscribers = 2
    first, second = _subscribe(port), _subscribe(port)
    refused = httpx.get(f"http://127.0.0.1:{port}/events")
    assert refused.status_code == 503 and refused.json() == {
        "detail": "2 event streams are open, the most this farm serves (2); close one and try again"}
    first.close()
    assert wait_for(lambda: len(hub.subscribers) == 1, timeout=DEADLINE_S), "the closed stream's slot is free"
    third = _subscribe(port)
    second.close()
    third.close()
    assert wait_for(lambda: not hub.subscribers, timeout=DEADLINE_S), "every slot is free"
    assert all(not device.guard.observers or all(o != hub.deliver for o in device.guard.observers)
               for device in farm.devices.values())  # nobody listens: the devices carry no observer of the hub


def test_keepalive_on_an_idle_stream(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    farm.http.hub.keepalive_s = 0.05
    with _subscribe(farm.http.port, "?kind=nothing-ever") as sock:
        assert b": keep-alive" in read_until(sock, b": keep-alive")


def test_a_reader_that_stops_loses_counted_events_and_slows_nobody(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    hub, port, device = farm.http.hub, farm.http.port, farm.devices["io"]
    hub.queue_size = 64
    sent = 0
    with _subscribe(port, "?kind=tcp%20connected", rcvbuf=4096) as sock:
        (subscriber,) = hub.subscribers
        deadline = time.monotonic() + DEADLINE_S
        # from this thread, as the Python API would: record() never waits for the stream
        while not (subscriber.lost_total and len(subscriber.queue) == hub.queue_size):  # full: the stream waits
            assert time.monotonic() < deadline and sent < 100_000, "the stream never stalled"
            for _ in range(100):
                device.record(TcpConnected(f"{sent:06} " + "x" * 2000))
                sent += 1
            time.sleep(0.001)  # lets the loop hand the batch out
        assert httpx.get(f"http://127.0.0.1:{port}/devices/io", timeout=DEADLINE_S).status_code == 200
        # the reader comes back: every event is either delivered, in order, or counted as lost
        delivered, lost, buffer = [], 0, b""
        while len(delivered) + lost < sent:
            chunk = sock.recv(1 << 16)
            assert chunk, "the stream ended early"
            buffer += chunk
            *blocks, buffer = buffer.split(b"\n\n")
            for block in blocks:
                if b"event: lost" in block:
                    lost += json.loads(block.rsplit(b"data: ", 1)[1])["lost"]
                elif b"data: " in block:
                    delivered.append(int(json.loads(block.split(b"data: ", 1)[1])["detail"][:6]))
    assert lost > 0 and len(delivered) + lost == sent
    assert delivered == sorted(delivered) and delivered[0] == 0


def test_a_stalled_stream_is_closed(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    hub, device = farm.http.hub, farm.devices["io"]
    hub.stall_s = 0.2
    with _subscribe(farm.http.port, rcvbuf=4096):
        deadline = time.monotonic() + DEADLINE_S
        while hub.subscribers:
            assert time.monotonic() < deadline, "the stalled stream is still open"
            for _ in range(50):
                device.record(TcpConnected("x" * 2000))
            time.sleep(0.01)


@pytest.mark.integration
def test_stopping_the_farm_ends_open_streams(free_address: AddressPool) -> None:
    from enip_farm.farm.farm import Farm

    config = parse_config({"devices": [{"name": "io", "address": free_address(), "model": "DSQC1030"}],
                           "discovery": False})
    farm = Farm(config, http=("127.0.0.1", 0))
    with farm.running_in_thread():
        sock = _subscribe(farm.http.port)
    with sock:
        assert read_all(sock).endswith(b"0\r\n\r\n")  # the chunked stream was ended, then the connection
