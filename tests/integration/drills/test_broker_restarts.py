"""Drill: the MQTT broker goes away and comes back, again and again, while the machine streams changes.

The simulator runs a program (its values arrive through the gateway's real OPC UA
source); the broker is stopped and started N times (3; 30 in soak). A QoS 1
subscriber with a persistent session must receive every change the tree
published for the machine's topics, in order, exactly once after folding QoS 1
retransmissions, and the retained topics must end at the latest values.

What is compared: the test holds its own `every_change` hub subscription, so it
knows each change the tree published and the exact payload the MQTT sink builds
for it (`encode_json` with the topic's route). A retransmission is byte-identical
(same value, same source timestamp): MQTT's QoS 1 is at-least-once, so a message
in flight when the broker stopped may come twice; those are counted and reported
(`redelivered`), and bounded by the number of restarts times the in-flight window.
A change missing, out of order or delivered as a second distinct message fails
the drill.

The broker is stopped with SIGTERM: Mosquitto then saves its persistence file,
which holds the subscriber's session and queued messages. (A SIGKILLed broker
loses what it had acknowledged but not yet saved; no client can get that back.)

A Sparkplug host watches the same gateway (its Sparkplug edge node, on the same
broker, over a connection of its own): the primary host, whose STATE gates the
births, with a session the broker keeps (`queue_qos0_messages`, since Sparkplug
data is QoS 0). After each reconnect it must see a new NBIRTH with the next bdSeq,
no gap in `seq` within a session, and every change of the machine's variables in
DDATA, live or historical (stored while the broker was away): none lost. A change
may come twice (live, then again historical when its message was not yet fenced
when the broker went); those are counted, not failed. Mosquitto publishes the
host's will (STATE offline) when it stops, so the edge node also ends sessions on
purpose (NDEATH, DISCONNECT, CONNECT again) and may connect more often than the
broker restarts: every CONNECT takes the next bdSeq, every NBIRTH repeats its
connection's, and every NDEATH names the session it ends.
"""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Iterator
from pathlib import Path

import pytest

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.model.hub import Change
from gateway.sinks.mqtt.payloads import encode_json
from gateway.sinks.mqtt.sink import MqttSink
from gateway.sinks.sparkplug.config import SparkplugConfig
from gateway.sinks.sparkplug.devices import millis
from gateway.sinks.sparkplug.sink import SparkplugSink
from simulator.runner import Simulator
from tests.integration.drills.conftest import Report, count
from tests.integration.drills.processes import laser_sim, write_yaml
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.integration.sparkplug.host import Seen, SparkplugHost
from tests.waiting import free_port, wait_until

RESTARTS = count("broker_restarts")
MACHINE = "laser-sim"
MAX_INFLIGHT = 200  # the gateway's window of unacknowledged messages (mqtt.max_inflight)
BROKER_INFLIGHT = 100  # Mosquitto's towards the subscriber (max_inflight_messages in its config)


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Mosquitto]:
    """Mosquitto with persistence, queueing QoS 0 messages too for a persistent session that is away."""
    mosquitto = Mosquitto(tmp_path / "mosquitto", free_port(), extra="queue_qos0_messages true\n")
    mosquitto.start()
    try:
        yield mosquitto
    finally:
        mosquitto.stop()


def sessions(messages: list[Seen]) -> list[list[Seen]]:
    """The host's messages split at each NBIRTH with a new bdSeq (a rebirth keeps its session)."""
    out: list[list[Seen]] = []
    current: int | None = None
    for seen in messages:
        if seen.kind == "NBIRTH":
            metric = seen.metric("bdSeq")
            bdseq = int(metric.value) if metric is not None else None
            if bdseq != current:
                out.append([])
                current = bdseq
        if out:
            out[-1].append(seen)
    return out


def seq_gaps(session: list[Seen]) -> int:
    gaps, previous = 0, None
    for seen in session:
        if seen.kind == "NDEATH":
            continue
        if seen.kind == "NBIRTH":
            previous = 0
            continue
        if previous is not None and seen.seq != (previous + 1) % 256:
            gaps += 1
        previous = seen.seq
    return gaps


def fold_redeliveries(payloads: list[bytes]) -> tuple[list[bytes], int]:
    """Drop byte-identical repeats (QoS 1 retransmissions); returns the rest, in order, and the count."""
    seen: set[bytes] = set()
    out = []
    for payload in payloads:
        if payload not in seen:
            seen.add(payload)
            out.append(payload)
    return out, len(payloads) - len(out)


@pytest.mark.timeout(90 + 12 * RESTARTS)
async def test_broker_restarts_lose_and_duplicate_nothing(
    broker: Mosquitto, recorders: list[Recorder], tmp_path: Path, drill_report: Report
) -> None:
    mosquitto = broker
    sim_port, gw_port = free_port(), free_port()
    store = tmp_path / "store"
    store.mkdir()
    mapping = load_mapping(write_yaml(tmp_path / "laser-sim.yaml", laser_sim(sim_port)), environ={})
    gateway = GatewayConfig.model_validate({
        "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway", "security": ["None"]},
        "state_dir": str(tmp_path / "state"),
    }).model_copy(update={
        "mqtt": mqtt_config(mosquitto.port, max_inflight=MAX_INFLIGHT),
        "sparkplug": SparkplugConfig(primary_host_id="drill-host"),  # the mqtt: section's broker
    })  # fmt: skip
    gw = Gateway(Config(gateway, (mapping,), tmp_path))
    machine = gw.tree.machines[MACHINE]
    # Before anything publishes: every change the tree makes from now on, in order, for the test.
    capture = gw.tree.hub.subscribe("drill:capture", every_change=True, limit=10_000_000)
    published: list[Change] = []

    def changes() -> int:
        published.extend(capture.take())
        return len(published)

    rec = subscriber(recorders, mosquitto.port, persistent=True, topics=[f"cnc/{MACHINE}/#"])
    host = SparkplugHost(mosquitto.port, host_id="drill-host", persistent=True).start()
    sim = Simulator(
        opcua_port=sim_port, ftp_port=free_port(), speed=20.0, store=store, loop_program="demo.nc"
    )
    await sim.__aenter__()
    sim_running = True
    try:
        async with gw:
            run = asyncio.create_task(gw.run(), name="gateway")
            sink: MqttSink = gw.sink("mqtt")
            edge: SparkplugSink = gw.sink("sparkplug", SparkplugSink)
            try:
                await wait_until(lambda: sink.online, timeout=15, message="the MQTT sink to connect")
                await wait_until(lambda: edge.online, timeout=15, message="the Sparkplug births")
                backlog_peak = 0
                for cycle in range(RESTARTS):
                    mark = len(rec.messages)
                    await wait_until(lambda m=mark: len(rec.messages) >= m + 50, timeout=15,
                                     message=f"changes flowing before stop {cycle + 1}")  # fmt: skip
                    await asyncio.to_thread(mosquitto.stop)
                    await wait_until(lambda: not sink.online, timeout=10, message="the sink to notice")
                    mark = changes()
                    await wait_until(lambda m=mark: changes() >= m + 100, timeout=15,
                                     message="changes while the broker is away")  # fmt: skip
                    assert sink.backlog is not None
                    backlog_peak = max(backlog_peak, len(sink.backlog))
                    await asyncio.to_thread(mosquitto.start)
                    await wait_until(lambda: sink.online, timeout=15, message=f"reconnect {cycle + 1}")
                    await wait_until(lambda: edge.online, timeout=15, message=f"Sparkplug births {cycle + 1}")
                # End the stream: the controller goes away, every value turns Bad (more changes), then quiet.
                await sim.__aexit__(None, None, None)
                sim_running = False
                await wait_until(lambda: not machine.status.is_connected, timeout=10, message="the drop")
                await wait_until(lambda: sink.settled, timeout=30, message="everything acknowledged")
                await wait_until(lambda: edge.settled, timeout=30, message="every DDATA fenced")
            finally:
                run.cancel()
                await asyncio.gather(run, return_exceptions=True)
            changes()
            routes = sink.routes.by_node
            expected: dict[str, list[bytes]] = {}
            for node, sample in published:
                route = routes.get(node)
                if route is None or node.internal:
                    continue  # status variables travel in the status document, not one by one
                expected.setdefault(route.topic, []).append(encode_json(sample, route.suffix))
            assert sink.backlog is not None
            dropped = sink.backlog.dropped_total
            # Sparkplug: every Good change of a mapped variable, by (metric name, source time in ms).
            changed = {(n.path, millis(s.source_ts)): s.value for n, s in published
                       if not n.internal and n.machine is machine and s.good}  # fmt: skip
            spb_dropped = edge.backlog.dropped_total if edge.backlog is not None else 0
            connects = edge.connects
    finally:
        if sim_running:
            await sim.__aexit__(None, None, None)
        host.stop()

    total = sum(len(v) for v in expected.values())

    def received(topic: str) -> list[bytes]:
        return [r.payload for r in rec.on(topic)]

    await wait_until(
        lambda: all(len(fold_redeliveries(received(t))[0]) >= len(v) for t, v in expected.items()),
        timeout=30, message="the subscriber to catch up",
    )  # fmt: skip
    missing = out_of_order = extra = redelivered = 0
    for topic, want in expected.items():
        got, again = fold_redeliveries(received(topic))
        redelivered += again
        missing += len(set(want) - set(got))
        extra += len(set(got) - set(want))
        if [p for p in got if p in set(want)] != [p for p in want if p in set(got)]:
            out_of_order += 1
    assert all(len(set(v)) == len(v) for v in expected.values())  # distinct changes have distinct payloads

    # A newcomer reads the retained topics: each ends at its latest value.
    late = subscriber(recorders, mosquitto.port, topics=[f"cnc/{MACHINE}/#"])
    await wait_until(lambda: all(late.last(t) for t in expected), timeout=15, message="the retained values")
    stale = [t for t, v in expected.items() if not (late.last(t).retain and late.last(t).payload == v[-1])]

    # The Sparkplug host's view: sessions, bdSeq, seq, and every change live or historical.
    spb = sessions(host.since(0))
    bdseqs = [int(session[0].metric("bdSeq").value) for session in spb]  # type: ignore[union-attr]
    gaps = sum(seq_gaps(session) for session in spb)
    # An NDEATH names the session it ends. One may arrive after the next session's NBIRTH (the broker
    # delivers the QoS 1 will and the QoS 0 births by separate queues): the bdSeq tells a host to ignore it.
    deaths = [(int(seen.metric("bdSeq").value), bdseq) for session, bdseq in zip(spb, bdseqs, strict=True)  # type: ignore[union-attr]
              for seen in session if seen.kind == "NDEATH"]  # fmt: skip
    late_deaths = sum(1 for death, born in deaths if death != born)
    live: dict[tuple[str, int], object] = {}
    historical: dict[tuple[str, int], object] = {}
    for seen in host.of("DDATA", MACHINE):
        for name, value, ts, is_historical in seen.values():
            (historical if is_historical else live)[(name, ts or 0)] = value
    spb_missing = [key for key in changed if key not in live and key not in historical]
    spb_wrong = [key for key, value in changed.items() if live.get(key, historical.get(key)) != value
                 and key not in spb_missing]  # fmt: skip
    drill_report(
        "broker restarts (Sparkplug)", restarts=RESTARTS, connects=connects, sessions=len(spb), bdseqs=bdseqs,
        seq_gaps=gaps, ndeaths=len(deaths), late_ndeaths=late_deaths,
        changes=len(changed), live=sum(1 for k in changed if k in live),
        historical=sum(1 for k in changed if k in historical and k not in live),
        twice=sum(1 for k in changed if k in historical and k in live), missing=len(spb_missing),
        wrong=len(spb_wrong), dropped=spb_dropped,
    )  # fmt: skip
    assert len(spb) >= RESTARTS + 1  # a new NBIRTH after each reconnect
    steps = [(b - a) % 256 for a, b in itertools.pairwise(bdseqs)]
    assert all(step >= 1 for step in steps)  # a new bdSeq each session, never one again
    assert (bdseqs[-1] - bdseqs[0]) % 256 == connects - 1  # one per CONNECT: the next after each
    assert gaps == 0
    assert spb_missing == [] and spb_wrong == [] and spb_dropped == 0
    assert sum(1 for k in changed if k in historical) > 0  # the outages' changes came, historical

    drill_report(
        "broker restarts", restarts=RESTARTS, topics=len(expected), published=total,
        received=sum(len(fold_redeliveries(received(t))[0]) for t in expected), duplicates=extra,
        redelivered=redelivered, missing=missing, out_of_order=out_of_order, dropped=dropped,
        backlog_peak=backlog_peak, resumed_sessions=rec.resumed, stale_retained=len(stale),
    )  # fmt: skip
    assert total >= RESTARTS * 100
    assert missing == 0 and extra == 0 and out_of_order == 0
    assert dropped == 0  # well within the store-and-forward limit
    assert redelivered <= RESTARTS * (MAX_INFLIGHT + BROKER_INFLIGHT)
    assert rec.resumed >= RESTARTS  # the subscriber's session survived each restart
    assert stale == []
