"""Prometheus exposition of the devices' counters and latency histograms, of the farm's health
(whether its cyclic I/O runs, the errors its loops met and went on from), and of the originators'
O->T packet intervals as the report measured them (cip/report.py): a histogram per class-1
connection, labelled with its device, in multiples of the connection's API (the buckets the
measurement keeps), so that `sum by (device)` gives a device's."""

from __future__ import annotations

import socket
import struct
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.registry import Collector

from enip_farm.protocol.connection import IO_PORT

#: Where Linux lists its UDP sockets with the datagrams each dropped (its receive buffer was full).
PROC_NET_UDP = Path("/proc/net/udp")


def udp_drops(port: int, table: Path = PROC_NET_UDP) -> dict[str, int]:
    """Datagrams the kernel dropped per local IPv4 address bound to `port` (the last column of
    /proc/net/udp); empty where there is no such table."""
    drops: dict[str, int] = {}
    try:
        lines = table.read_text().splitlines()[1:]
    except OSError:
        return drops
    suffix = f":{port:04X}"
    for line in lines:
        fields = line.split()
        if len(fields) >= 13 and fields[1].endswith(suffix):
            host = socket.inet_ntoa(struct.pack("<I", int(fields[1][:8], 16)))
            drops[host] = drops.get(host, 0) + int(fields[-1])
    return drops


class FarmCollector(Collector):
    """Reads the devices' counters at scrape time; nothing is counted twice."""

    def __init__(self, devices: Iterable, health: Callable[[], dict[str, Any]] | None = None,
                 load: Callable[[], dict[str, Any]] | None = None, report: Callable[[], Any] | None = None) -> None:
        self.devices = list(devices)
        self.health = health
        self.load = load
        self.report = report

    def collect(self) -> Iterator:
        requests = CounterMetricFamily("enip_farm_requests", "Explicit requests by CIP service and general status",
                                       labels=["device", "service", "status"])
        connections = CounterMetricFamily("enip_farm_tcp_connections", "TCP connections accepted", labels=["device"])
        open_io = GaugeMetricFamily("enip_farm_io_connections", "Open CIP connections by kind",
                                    labels=["device", "kind"])
        packets = CounterMetricFamily("enip_farm_class1_packets", "Class-1 packets", labels=["device", "direction"])
        latency = HistogramMetricFamily("enip_farm_request_seconds", "Time from request bytes to reply write",
                                        labels=["device"])
        for device in self.devices:
            name = device.name
            for (service, status), count in sorted(device.router.request_counts.items()):
                requests.add_metric([name, f"0x{service:02X}", f"0x{status:02X}"], count)
            connections.add_metric([name], device.counters["tcp_connections"])
            kinds: dict[str, int] = {}
            for connection in list(device.connections.values()):
                kinds[connection.kind.value] = kinds.get(connection.kind.value, 0) + 1
            for kind, count in kinds.items():
                open_io.add_metric([name, kind], count)
            packets.add_metric([name, "o_t"], device.counters["o_t_packets"])
            packets.add_metric([name, "t_o"], device.counters["t_o_packets"])
            latency.add_metric([name], device.latency.buckets(), device.latency.sum)
        io_errors = CounterMetricFamily("enip_farm_io_errors", "Exceptions of a device's cyclic I/O (it goes on)",
                                        labels=["device"])
        kernel_drops = CounterMetricFamily("enip_farm_class1_kernel_drops", "O->T datagrams the kernel dropped "
                                           "before the farm read them (UDP 2222 receive buffer full)",
                                           labels=["device"])
        drops = udp_drops(IO_PORT)
        for device in self.devices:
            io_errors.add_metric([device.name], device.counters["io_errors"])
            kernel_drops.add_metric([device.name], drops.get(device.profile.address, 0))
        yield from (requests, connections, open_io, packets, latency, io_errors, kernel_drops)
        if self.report is not None:
            yield intervals(self.report())
        if self.health is not None:
            health = self.health()
            yield GaugeMetricFamily("enip_farm_cyclic_io_running", "1 while the cyclic I/O thread runs",
                                    value=int(health["cyclic_io"]["running"]))
            yield CounterMetricFamily("enip_farm_cyclic_io_loop_errors", "Unexpected exceptions of the cyclic I/O "
                                      "thread's loop (it goes on)", value=health["cyclic_io"]["errors"])
            yield CounterMetricFamily("enip_farm_event_loop_errors", "Exceptions that escaped a callback or task "
                                      "of the event loop", value=health["loop_errors"])
        if self.load is not None:
            load = self.load()
            yield GaugeMetricFamily("enip_farm_cyclic_io_budget_datagrams_per_second", "Class-1 datagrams per "
                                    "second this worker admits connections for", value=load["budget_datagrams_per_s"])
            yield GaugeMetricFamily("enip_farm_cyclic_io_reserved_datagrams_per_second", "What the open "
                                    "connections take of the budget", value=load["reserved_datagrams_per_s"])
            yield CounterMetricFamily("enip_farm_cyclic_io_budget_refusals", "Forward Opens refused (0x0113) "
                                      "for want of budget", value=load["refused"])
            yield GaugeMetricFamily("enip_farm_cyclic_io_lag_seconds", "How late the cyclic I/O thread ran "
                                    "behind its schedule, worst of the last second", value=load["lag_s"])
            yield CounterMetricFamily("enip_farm_cyclic_io_overloads", "Wake-ups of the cyclic I/O thread more "
                                      "than 5 ms late: the farm overloaded", value=load["overloads"])


def intervals(report: Any) -> HistogramMetricFamily:
    """Each measured connection's O->T intervals (open ones and the last that ended) as a histogram
    in APIs: `le` the bucket bounds, `_sum` the intervals' total in APIs."""
    family = HistogramMetricFamily("enip_farm_o_t_interval_apis", "O->T packet interval of each class-1 "
                                   "connection, in multiples of its API (kernel receive times)",
                                   labels=["device", "connection", "originator"])
    for device in report.devices:
        for connection in device.connections:
            figures = connection.intervals
            histogram, seen, buckets = figures.histogram, 0, []
            for bound, count in zip((*histogram.bounds_api, float("inf")), histogram.counts, strict=True):
                seen += count
                buckets.append(("+Inf" if bound == float("inf") else repr(bound), seen))
            total = (figures.mean_ns or 0) * figures.count / figures.api_ns
            family.add_metric([device.device, f"0x{connection.o_t_id:08X}", connection.originator], buckets, total)
    return family
