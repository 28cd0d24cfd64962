"""`/metrics` in Prometheus' text format: the one module that imports prometheus_client.

A scrape first gathers what needs the event loop or a thread (job counts from the
queue, the diagnostics snapshot) into a `Scrape`; the collector then turns it into
metric families, and prometheus_client's own process collector adds CPU seconds and
resident memory (`process_cpu_seconds_total`, `process_resident_memory_bytes`).

| metric | labels | what |
|---|---|---|
| `cnc_gateway_up` | | 1 while the gateway answers |
| `cnc_gateway_ready` | | 1 once every configured sink is up and every machine has been tried |
| `cnc_gateway_info` | version | the version |
| `cnc_gateway_machine_connected` | machine | 1 while its controller link is up |
| `cnc_gateway_machine_reconnects_total` | machine | links re-established |
| `cnc_gateway_machine_changes_total` | machine | value changes taken into the tree (rate(): changes/s) |
| `cnc_gateway_machine_variables` | machine, quality | mapped variables by quality (good, uncertain, bad) |
| `cnc_gateway_machine_alarms_active` | machine | active alarms |
| `cnc_gateway_machine_jobs` | machine, state | jobs in the queue by state |
| `cnc_gateway_dnc_bytes_sent` | machine | bytes of the drip-fed job the controller took |
| `cnc_gateway_dnc_lead_seconds` | machine | seconds of program the controller holds ahead of its block |
| `cnc_gateway_sink_backlog` | sink | changes waiting for the sink (hub subscription), or its own queue |
| `cnc_gateway_sink_dropped_total` | sink | messages its bounded queue dropped |
| `cnc_gateway_sink_coalesced_total` | sink | changes replaced by a newer one before the sink took them |
| `cnc_gateway_sink_messages_total` | sink | changes the sink took from the hub (rate(): messages/s) |
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

from prometheus_client import CollectorRegistry, ProcessCollector, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.exposition import CONTENT_TYPE_LATEST
from prometheus_client.registry import Collector

CONTENT_TYPE = CONTENT_TYPE_LATEST


@dataclass
class MachineFigures:
    connected: bool
    reconnects: int
    changes: int
    quality: Mapping[str, int]
    alarms_active: int | None = None
    jobs: Mapping[str, int] | None = None
    dnc_sent: float | None = None
    dnc_lead: float | None = None


@dataclass
class Scrape:
    version: str
    ready: bool
    machines: dict[str, MachineFigures] = field(default_factory=dict)
    diagnostics: Mapping[str, Any] = field(default_factory=dict)


class _Gateway(Collector):
    def __init__(self) -> None:
        self.scrape: Scrape | None = None

    def collect(self) -> Iterator[Metric]:
        s = self.scrape
        if s is None:
            return
        up = GaugeMetricFamily("cnc_gateway_up", "1 while the gateway answers")
        up.add_metric([], 1)
        yield up
        ready = GaugeMetricFamily("cnc_gateway_ready", "1 once every sink is up and every machine was tried")
        ready.add_metric([], 1 if s.ready else 0)
        yield ready
        info = GaugeMetricFamily("cnc_gateway_info", "The gateway's version", labels=["version"])
        info.add_metric([s.version], 1)
        yield info
        yield from self._machines(s)
        yield from self._sinks(s)

    def _machines(self, s: Scrape) -> Iterator[Metric]:
        m = ["machine"]
        connected = GaugeMetricFamily(
            "cnc_gateway_machine_connected", "1 while the controller link is up", labels=m
        )
        reconnects = CounterMetricFamily(
            "cnc_gateway_machine_reconnects", "Controller links re-established", labels=m
        )
        changes = CounterMetricFamily(
            "cnc_gateway_machine_changes", "Value changes taken into the tree", labels=m
        )
        variables = GaugeMetricFamily(
            "cnc_gateway_machine_variables", "Mapped variables by quality", labels=["machine", "quality"]
        )
        alarms = GaugeMetricFamily("cnc_gateway_machine_alarms_active", "Active alarms", labels=m)
        jobs = GaugeMetricFamily("cnc_gateway_machine_jobs", "Jobs by state", labels=["machine", "state"])
        sent = GaugeMetricFamily(
            "cnc_gateway_dnc_bytes_sent", "Bytes of the drip-fed job the controller has taken", labels=m
        )
        lead = GaugeMetricFamily(
            "cnc_gateway_dnc_lead_seconds",
            "Seconds of program the controller holds ahead of its block",
            labels=m,
        )
        for name, f in sorted(s.machines.items()):
            connected.add_metric([name], 1 if f.connected else 0)
            reconnects.add_metric([name], f.reconnects)
            changes.add_metric([name], f.changes)
            for quality, count in sorted(f.quality.items()):
                variables.add_metric([name, quality], count)
            if f.alarms_active is not None:
                alarms.add_metric([name], f.alarms_active)
            for state, count in sorted((f.jobs or {}).items()):
                jobs.add_metric([name, state], count)
            if f.dnc_sent is not None:
                sent.add_metric([name], f.dnc_sent)
            if f.dnc_lead is not None:
                lead.add_metric([name], f.dnc_lead)
        yield from (connected, reconnects, changes, variables, alarms, jobs, sent, lead)

    def _sinks(self, s: Scrape) -> Iterator[Metric]:
        labels = ["sink"]
        backlog = GaugeMetricFamily("cnc_gateway_sink_backlog", "Changes or messages waiting", labels=labels)
        dropped = CounterMetricFamily(
            "cnc_gateway_sink_dropped", "Messages a bounded queue dropped", labels=labels
        )
        coalesced = CounterMetricFamily(
            "cnc_gateway_sink_coalesced",
            "Changes replaced by a newer one before the sink took them",
            labels=labels,
        )
        messages = CounterMetricFamily(
            "cnc_gateway_sink_messages", "Changes taken from the hub", labels=labels
        )
        resent = CounterMetricFamily(
            "cnc_gateway_sink_resent",
            "Messages sent again (MQTT DUP) after the link dropped before their acknowledgement",
            labels=labels,
        )
        hub = s.diagnostics.get("hub", {})
        sinks = s.diagnostics.get("sinks", {})
        for name, sub in sorted(hub.items()):
            own = sinks.get(name, {})
            backlog.add_metric([name], own.get("backlog", sub.get("backlog", 0)))
            coalesced.add_metric([name], sub.get("coalesced", 0))
            messages.add_metric([name], sub.get("delivered", 0))
            if "dropped" in own:
                dropped.add_metric([name], own["dropped"])
            if "resent" in own:
                resent.add_metric([name], own["resent"])
        yield from (backlog, dropped, coalesced, messages, resent)


class Metrics:
    """One registry: the gateway's figures and the process's. `render(scrape)` is the response body."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=False)
        self._gateway = _Gateway()
        self.registry.register(self._gateway)
        ProcessCollector(registry=self.registry)

    def render(self, scrape: Scrape) -> bytes:
        self._gateway.scrape = scrape
        try:
            return bytes(generate_latest(self.registry))
        finally:
            self._gateway.scrape = None
