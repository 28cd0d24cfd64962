"""The Sparkplug B sink: the gateway as one edge node, each machine a device, from the same tree.

A session (Sparkplug 3.0, chapter 5):
1. CONNECT with a clean session and the NDEATH as will (QoS 1, not retained), carrying the bdSeq of
   this connection (bdseq.py); subscribe to NCMD, every device's DCMD and, with a primary host, its
   STATE;
2. once the primary host's STATE says online (at once without one): NBIRTH (seq 0, bdSeq, the
   node's own metrics, node.py), then one DBIRTH per machine (devices.py), followed by a DDEATH for
   a machine whose controller is away, so that a host knows every metric even then;
3. each publishing cycle (one batch of the tree's changes), one DDATA per machine that changed:
   its changes by alias, with source timestamps, seq running over every message of the node;
4. a controller that drops: DDEATH (its Bad values go with it, not as data); back: DBIRTH again.
   Bad quality while the controller is reachable is a `Quality` property in DDATA, not a death;
5. NCMD rebirth: NBIRTH and every DBIRTH again; DCMD: writes and commands (commands.py);
6. the primary host's STATE offline: NDEATH, DISCONNECT, and the session starts over (5.x);
   a clean stop: NDEATH, then DISCONNECT; a crash: the broker publishes the will.

Store-and-forward: while there is no session (no broker, or the primary host offline), changes
are kept in the MQTT link's `Backlog` (with its optional SQLite journal), one stored DDATA per
machine and cycle, by name and marked historical (the codec's `encode_stored`). After the next
births they go out oldest first, with this session's aliases and seq (`release_stored`), beside
the live data, which is never held back for them: every message is either live or historical.

QoS 0 data has no acknowledgement, so a message written to a socket the broker then drops would be
lost without anyone knowing. The broker answers the packets of one connection in order, so after
each cycle the sink sends an UNSUBSCRIBE of a topic it never subscribed to (`FENCE`): its UNSUBACK
says the broker has taken everything before it. What was sent but not yet fenced when the
connection drops goes back to the store, and out again, historical: a change may arrive twice
(once live, once historical), never not at all. A clean stop's NDEATH, at QoS 1, fences with its PUBACK.

Ordering: the hot path (`_process`) never awaits. Births, device births and the outcome DDATA of
a refused write first take whatever the hub holds (`_quiesce`) under the same lock as the
publishing cycle, so that no older change is published after a birth that already has its value.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Self

from gateway.codecs.sparkplug import (
    NAMESPACE,
    MessageType,
    Metric,
    PrimaryHost,
    Quality,
    Seq,
    SparkplugError,
    Unencodable,
    command_subscriptions,
    encode_dbirth,
    encode_ddata,
    encode_ddeath,
    encode_nbirth,
    encode_ndata,
    encode_ndeath,
    encode_stored,
    node_topic,
    parse_state,
    release_stored,
    state_topic,
)
from gateway.codecs.sparkplug.aliases import Aliases
from gateway.errors import BrokerError
from gateway.model.hub import Change, Subscription
from gateway.model.status import STANDBY_STATUS
from gateway.model.tree import VariableNode, VariableTree
from gateway.sinks.base import SinkHealth
from gateway.sinks.mqtt_link.buffer import Message
from gateway.sinks.mqtt_link.client import Connected, Incoming, MqttClient, Will, default_client_id
from gateway.sinks.mqtt_link.link import (
    REMIND_EVERY,
    STATE_CONNECTED,
    STATE_DISCONNECTED,
    BrokerLink,
    Wording,
    broker_settings,
)
from gateway.sinks.mqtt_link.requests import report_roles
from gateway.sinks.sparkplug.bdseq import FILE as BDSEQ_FILE
from gateway.sinks.sparkplug.bdseq import BdSeqStore
from gateway.sinks.sparkplug.commands import Outcomes, Requests
from gateway.sinks.sparkplug.config import SUFFIX, SparkplugBroker, SparkplugConfig
from gateway.sinks.sparkplug.devices import (
    QUALITY_PROPERTY,
    CommandMetric,
    Device,
    DeviceMapping,
    VariableMetric,
    millis,
    now_ms,
)
from gateway.sinks.sparkplug.node import NodeMetrics, SinkCounters

log = logging.getLogger(__name__)

BACKLOG_FILE = "sparkplug-backlog.sqlite3"
FENCE = "cnc-gateway/sparkplug-fence"  # never subscribed: unsubscribing from it is the fence
YIELD_EVERY = 2000  # changes handled between turns for the rest of the loop
MAX_METRICS = 2000  # metrics per DDATA; a larger cycle of one machine goes out in several
REPLAY_WINDOW = 64  # stored messages out and not yet fenced
HUB_LIMIT = 100_000  # changes the hub keeps in order for this sink before it keeps the latest per variable
PAHO_QUEUE_LIMIT = 50_000  # packets paho may hold for a stuck socket before live data is stored instead
SHUTDOWN_FLUSH = 1.0  # s allowed on the way out for the broker to take what is in flight
STATE_WAITING, STATE_ONLINE = "connected, waiting for the primary host", "online"
WORDING = Wording(
    label="Sparkplug",
    check="check the credentials and the broker's ACL",
    waiting="DDATA messages stored",
    kept="DDATA messages",
    lost="stored DDATA messages",
)


class _Sent:
    """A DDATA handed to the broker and not yet fenced: live metrics, or a stored message replayed."""

    __slots__ = ("device", "message", "metrics")

    def __init__(self, device: Device, metrics: list[Metric] | None, message: Message | None) -> None:
        self.device = device
        self.metrics = metrics
        self.message = message


class SparkplugSink(BrokerLink):
    """Mirrors the variable tree to a Sparkplug B host (implements gateway.sinks.base.Sink)."""

    name = "sparkplug"

    def __init__(
        self,
        tree: VariableTree,
        config: SparkplugConfig,
        broker: SparkplugBroker,
        state_dir: Path,
        mappings: Mapping[str, DeviceMapping],
        *,
        base_dir: Path | None = None,
    ) -> None:
        self.tree = tree
        self.config = config
        self.state_dir = state_dir
        self.mappings = mappings
        self.group_id = config.group_id
        self.edge_node_id = config.edge_node_id
        self.nbirth_topic = node_topic(self.group_id, MessageType.NBIRTH, self.edge_node_id)
        self.ndata_topic = node_topic(self.group_id, MessageType.NDATA, self.edge_node_id)
        self.ndeath_topic = node_topic(self.group_id, MessageType.NDEATH, self.edge_node_id)
        host_id = config.primary_host_id
        self.state_topic = state_topic(host_id) if host_id is not None else None
        self.host = PrimaryHost() if host_id is not None else None
        settings = broker_settings(
            broker,
            base_dir,
            client_id=broker.client_id or (default_client_id()[: 64 - len(SUFFIX)] + SUFFIX),
            max_packet_size=config.max_packet_size,
            no_delay=True,  # a DDATA, then its fence: neither should wait for the broker's delayed ACK
        )
        super().__init__(settings, broker.reconnect, WORDING, log)
        self.aliases = Aliases()
        self.seq = Seq()
        self.devices: dict[str, Device] = {}
        self.node: NodeMetrics | None = None
        self.requests: Requests | None = None
        self.bdseq: int | None = None  # this session's
        self.connected = False  # an MQTT session is up
        self.born = False  # and its NBIRTH is out
        self.births = 0  # NBIRTHs published (each followed by every DBIRTH)
        self.published = 0  # messages handed to the broker
        self.changes_published = 0  # metric values in live DDATA
        self.changes_stored = 0  # metric values kept for later
        self.replayed = 0  # stored messages the broker has taken
        self._client: MqttClient | None = None
        self._store: BdSeqStore | None = None
        self._sub: Subscription[VariableNode] | None = None
        self._metric_of: dict[VariableNode, VariableMetric] = {}
        self._late: dict[VariableNode, Device] = {}  # nodes that appeared after the births: in the next ones
        self._unknown: set[VariableNode] = set()
        self._lock = asyncio.Lock()
        self._wake = asyncio.Event()  # the births task has something to look at
        self._birth_wanted = False
        self._session_end = asyncio.Event()
        self._leaving: str | None = None  # why the session ends cleanly (the primary host went offline)
        self._unconfirmed: list[_Sent] = []
        self._replays = 0  # replayed messages among them
        self._fence_mid: int | None = None
        self._fence_covers = 0
        self._ndeath_mid: int | None = None
        self._ndeath_acked = asyncio.Event()
        self._fenced = asyncio.Event()  # set while nothing sent waits for its fence
        self._unencodable: set[str] = set()

    # --- what others read ----------------------------------------------------------------------

    @property
    def online(self) -> bool:
        """Born: births are out and data goes out live."""
        return self.born

    @property
    def in_flight(self) -> int:
        return len(self._unconfirmed)

    @property
    def refusals(self) -> Mapping[str, int]:
        return self.requests.refusals if self.requests is not None else {}

    @property
    def settled(self) -> bool:
        """Nothing left to do: every change taken, published and fenced, nothing stored."""
        sub = self._sub
        return (
            sub is not None
            and not sub.backlog
            and not self._unconfirmed
            and not self.backlog
            and not any(d.pending for d in self.devices.values())
        )

    def topics(self) -> list[str]:
        """The topics this edge node publishes on (for the start-up line and the demo's banner)."""
        g, e = self.group_id, self.edge_node_id
        return [
            f"{NAMESPACE}/{g}/{{NBIRTH,NDATA,NDEATH}}/{e}",
            f"{NAMESPACE}/{g}/{{DBIRTH,DDATA,DDEATH}}/{e}/{{{','.join(self.tree.machines)}}}",
        ]

    # --- lifecycle -----------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        buffer = self.config.buffer
        self._open_backlog(buffer.limit, self.state_dir / BACKLOG_FILE if buffer.persist else None)
        self._store = BdSeqStore(self.state_dir / BDSEQ_FILE)
        # Subscribe before the devices read their controllers' state, so no change falls between the two.
        self._sub = self.tree.hub.subscribe(self.name, every_change=True, limit=HUB_LIMIT)
        g, e = self.group_id, self.edge_node_id
        self.devices = {
            name: Device(machine, g, e, self.aliases, self.mappings.get(name))
            for name, machine in self.tree.machines.items()
        }
        self._metric_of = {node: m for d in self.devices.values() for node, m in d.variables.items()}
        counters = SinkCounters(
            dropped=lambda: self.backlog.dropped_total if self.backlog is not None else 0,
            stored=lambda: len(self.backlog) if self.backlog is not None else 0,
            refused=lambda: self.requests.refused if self.requests is not None else 0,
        )
        node = self.node = NodeMetrics(self.tree, self.aliases, counters)
        outcomes = Outcomes(self._rebirth, self._show_variable, self._show_command)
        self.requests = Requests(
            self.tree, g, e, self.devices, lambda: node.table, outcomes, self.config.max_pending_writes
        )
        host = f"; primary host {self.config.primary_host_id}" if self.host is not None else ""
        log.info(
            "Sparkplug: edge node %s/%s, devices %s, on %s; broker %s as %s%s",
            g,
            e,
            ", ".join(self.devices),
            " and ".join(self.topics()),
            self.endpoint,
            self.settings.client_id,
            host,
        )
        self._report_writers()
        return self

    def _report_writers(self) -> None:
        report_roles(
            self.tree,
            (
                (
                    device.machine,
                    [m.node for m in device.variables.values() if m.writable],
                    any(c.enabled for c in device.commands),
                )
                for device in self.devices.values()
            ),
            log,
            refused="Sparkplug: %s: DCMD writes and commands the mapping opens are refused: they have "
            "no role (mapping: mqtt.writer_role, or access.mqtt_writer_role)",
            acts="Sparkplug: DCMD to %s acts as %s and may %s",
        )

    async def __aexit__(self, *exc_info: object) -> None:
        client = self._client
        try:
            if client is not None and self.connected:
                await self._say_goodbye(client)
            elif client is not None:
                client.close()
        finally:
            self._session_over("gateway stopped")
            self._close_backlog()
            if self._sub is not None:
                self._sub.close()
                self._sub = None

    async def _say_goodbye(self, client: MqttClient) -> None:
        """What is pending goes out; then the NDEATH (the specification's clean stop), then DISCONNECT."""
        async with self._lock:
            self._quiesce()
            self._fence()
            self._commit()
        if self._unconfirmed:
            self._fenced.clear()
            try:
                async with asyncio.timeout(SHUTDOWN_FLUSH):
                    await self._fenced.wait()
            except TimeoutError:
                pass
        self.born = False
        if self.connected and self.bdseq is not None:
            self._send_ndeath()
            try:
                async with asyncio.timeout(SHUTDOWN_FLUSH / 2):
                    await self._ndeath_acked.wait()
                self._confirm(len(self._unconfirmed))  # the broker took everything before the NDEATH
            except TimeoutError:
                pass
        await client.disconnect()

    def health(self) -> SinkHealth:
        """Ready once the edge node is online: connected, and its NBIRTH and DBIRTHs published (connected
        alone, or waiting for the primary host, is not yet serving Sparkplug consumers)."""
        return self._health(ready=self.state == STATE_ONLINE, in_flight=self.in_flight, online=self.online)

    async def run(self) -> None:
        """Keep the session, publish the changes, carry out commands; until cancelled."""
        if self._sub is None or self.requests is None:
            raise RuntimeError("enter the Sparkplug sink before running it")
        requests = self.requests
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self._connection(), name="sparkplug:connection")
            tg.create_task(self._drain(self._sub), name="sparkplug:publish")
            tg.create_task(self._births_task(), name="sparkplug:births")
            tg.create_task(self._tick(), name="sparkplug:tick")
            for machine in requests.writes:
                tg.create_task(requests.write_worker(machine), name=f"sparkplug:writes:{machine}")
            for machine in requests.calls:
                tg.create_task(requests.call_worker(machine), name=f"sparkplug:commands:{machine}")

    # --- the session ---------------------------------------------------------------------------

    def _new_client(self, bdseq: int) -> MqttClient:
        will = Will(
            self.ndeath_topic, encode_ndeath(bdseq=bdseq), MessageType.NDEATH.qos, MessageType.NDEATH.retain
        )
        settings = dataclasses.replace(self.settings, will=will)
        client: MqttClient = MqttClient(
            settings,
            on_message=self._incoming,
            on_published=lambda mid: self._published(client, mid),
            on_lost=lambda reason: self._lost(client, reason),
            on_unsubscribed=lambda mid: self._unsubscribed(client, mid),
        )
        return client

    async def _connection(self) -> None:
        await self._keep_connected(self._connect, self._session)

    async def _connect(self) -> tuple[MqttClient, int, Connected]:
        """A new client (its will carries the next bdSeq), connected."""
        assert self._store is not None
        bdseq = self._store.candidate()
        client = self._new_client(bdseq)
        try:
            info = await client.connect()
        except BrokerError:
            client.close()
            raise
        return client, bdseq, info

    async def _session(self, opened: tuple[MqttClient, int, Connected]) -> bool:
        """Until the connection is lost (False), or the primary host went offline: NDEATH, DISCONNECT,
        and a new session at once (True)."""
        client, bdseq, info = opened
        self._session_started(client, bdseq, info)
        await self._session_end.wait()
        self._session_end.clear()
        leaving, self._leaving = self._leaving, None
        if leaving is None:
            return False
        await self._leave(client, leaving)
        return True

    def _session_started(self, client: MqttClient, bdseq: int, info: Connected) -> None:
        assert self._store is not None
        self._client = client
        self._store.established(bdseq)
        self.bdseq = bdseq
        self.connected = True
        self.connects += 1
        self._ndeath_mid = None
        self._ndeath_acked.clear()
        self._session_end.clear()  # what ended the last session (a loss while leaving it) is over
        self._leaving = None
        try:
            client.subscribe(list(command_subscriptions(self.group_id, self.edge_node_id)), qos=1)
            if self.state_topic is not None:
                client.subscribe([self.state_topic], qos=1)
        except BrokerError as exc:
            log.error("Sparkplug: %s; commands and the primary host's STATE will not arrive", exc.reason)
        if self.host is not None:
            self.host.reset()  # its retained STATE comes again with the subscription
        self._set_state(STATE_CONNECTED if self.host is None else STATE_WAITING, "")
        stored = len(self.backlog) if self.backlog is not None else 0
        self._outage.recovered(
            "Sparkplug: connected to %s as %s (bdSeq %d)%s%s",
            self.endpoint,
            self.settings.client_id,
            bdseq,
            f"; waiting for the primary host {self.config.primary_host_id}" if self.host is not None else "",
            f"; {stored} stored DDATA messages to deliver" if stored else "",
        )
        self._birth_wanted = True
        self._wake.set()

    async def _leave(self, client: MqttClient, reason: str) -> None:
        """End the session on purpose: NDEATH (QoS 1), DISCONNECT. What was not fenced goes back to the store,
        even though the NDEATH's PUBACK says the broker has it: the primary host it was for had gone."""
        log.warning("Sparkplug: %s: NDEATH, disconnecting, and starting the session again", reason)
        async with self._lock:
            self.born = False
            self._send_ndeath()
        try:
            async with asyncio.timeout(SHUTDOWN_FLUSH):
                await self._ndeath_acked.wait()
        except TimeoutError:
            pass
        self._session_over(reason)
        await client.disconnect()

    def _lost(self, client: MqttClient, reason: str) -> None:
        if client is not self._client or not self.connected:
            return
        client.take_back()
        self._session_over(f"connection lost: {reason}")
        log.warning(
            "Sparkplug: connection to %s lost (%s); storing data until it is back", self.endpoint, reason
        )
        self._session_end.set()

    def _session_over(self, reason: str) -> None:
        """No session any more: nothing is live; what was sent and not fenced goes back to the store."""
        self.connected = False
        self.born = False
        self._birth_wanted = False
        for device in self.devices.values():
            device.alive = False
            device.birth_due = False
        self._fence_mid = None
        unconfirmed, self._unconfirmed = self._unconfirmed, []
        self._replays = 0
        backlog = self.backlog
        if backlog is not None and unconfirmed:
            backlog.put_front([s.message for s in unconfirmed if s.message is not None])
            for sent in unconfirmed:
                if sent.metrics:
                    self._keep(sent.device, sent.metrics)
            self._commit()
        if self.state != STATE_DISCONNECTED:
            self._set_state(STATE_DISCONNECTED, reason)

    # --- births ---------------------------------------------------------------------------------

    def _ready(self) -> bool:
        return self._birth_wanted and self.connected and (self.host is None or self.host.online)

    def _rebirth(self) -> None:
        """A host asked for every birth again (or a variable appeared): at the next quiet moment."""
        if self.connected:
            self._birth_wanted = True
            self._wake.set()

    async def _births_task(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            if not self._ready():
                continue
            async with self._lock:
                if self._ready():
                    self._births()

    def _births(self) -> None:
        """NBIRTH, then every DBIRTH (and a DDEATH after it for a machine that is away); then stored data."""
        assert self.node is not None and self.bdseq is not None
        self._quiesce()  # what happened before the births: published, or stored if the session is new
        self._birth_wanted = False
        for node, device in self._late.items():  # variables that appeared since: in these births
            self._metric_of[node] = device.add(node)
        self._late.clear()
        ts, bdseq = now_ms(), self.bdseq
        nbirth = self._encode_birth(
            lambda ms: encode_nbirth(ms, bdseq=bdseq, seq=self.seq, timestamp=ts), self.node.current(ts)
        )
        if nbirth is None:
            log.error("Sparkplug: the NBIRTH cannot be encoded; nothing is published until a rebirth")
            return
        self._send(self.nbirth_topic, nbirth)
        self.born = True
        self.births += 1
        self._set_state(STATE_ONLINE, "")
        for device in self.devices.values():
            self._dbirth(device)
        born = sum(1 for name in self.devices if name not in self.tree.standby)  # shard: lease: its own only
        log.info("Sparkplug: NBIRTH (bdSeq %d) and %d DBIRTHs published", self.bdseq, born)
        self._replay()
        self._fence()

    def _dbirth(self, device: Device) -> None:
        if device.name in self.tree.standby:  # another shard's edge node serves it: not born here
            device.birth_due = False
            device.alive = False
            return
        ts = now_ms()
        payload = self._encode_birth(
            lambda ms: encode_dbirth(ms, seq=self.seq, timestamp=ts), device.birth_metrics()
        )
        if payload is None:
            log.error("Sparkplug: the DBIRTH of %s cannot be encoded; the device is not born", device.name)
            return
        self._send(device.dbirth, payload)
        device.birth_due = False
        device.alive = device.online
        if not device.online:
            self._send(device.ddeath, encode_ddeath(seq=self.seq, timestamp=ts))

    def _encode_birth(self, encode: Callable[[list[Metric]], bytes], metrics: list[Metric]) -> bytes | None:
        """A birth carries every metric: one whose value its type cannot carry goes as a null, Bad."""
        nulled: set[str] = set()
        bad = QUALITY_PROPERTY[Quality.BAD]
        while True:
            try:
                return encode(metrics)
            except Unencodable as exc:
                name = exc.metric
                if name is None or name in nulled or not any(m.name == name for m in metrics):
                    log.error("Sparkplug: cannot encode a birth: %s", exc)
                    return None
                nulled.add(name)
                self._unencodable_once(exc)
                metrics = [
                    dataclasses.replace(m, value=None, properties={**m.properties, **bad})
                    if m.name == name
                    else m
                    for m in metrics
                ]

    # --- the changes ----------------------------------------------------------------------------

    async def _drain(self, sub: Subscription[VariableNode]) -> None:
        while True:
            batch = await sub.next_batch()
            async with self._lock:
                for start in range(0, len(batch), YIELD_EVERY):
                    if start:
                        await asyncio.sleep(0)
                    self._process(batch[start : start + YIELD_EVERY])
                self._end_cycle()

    def _end_cycle(self) -> None:
        self._quiesce()
        for device in self.devices.values():
            if device.birth_due and self.born:
                self._dbirth(device)
        self._fence()
        self._commit()

    def _quiesce(self) -> None:
        """Take everything the hub holds for this sink, and publish or store it, without awaiting."""
        sub = self._sub
        if sub is not None:
            while sub.backlog:
                self._process(sub.take())
        for device in self.devices.values():
            if device.pending:
                self._flush(device)

    def _process(self, batch: list[Change[VariableNode]]) -> None:
        """The hot path: each change into its device's list for this cycle (or past a device that is away)."""
        metric_of = self._metric_of
        born = self.born
        for node, sample in batch:
            metric = metric_of.get(node)
            if metric is None:
                self._appeared(node)
                continue
            device = metric.device
            if node is device.connected_node:
                self._connection_change(
                    device, sample.value is True and sample.good, millis(sample.source_ts)
                )
            if (device.alive if born else device.online) and sample.status != STANDBY_STATUS:
                device.pending.append((metric, sample))

    def _appeared(self, node: VariableNode) -> None:
        """A variable added after start-up: it is in the next births (a rebirth, if the session is born)."""
        if node in self._late or node in self._unknown:
            return
        device = self.devices.get(node.machine.name)
        if device is None:
            self._unknown.add(node)
            log.warning("Sparkplug: %s belongs to no device of this edge node; not published", node.full_path)
            return
        self._late[node] = device
        self._rebirth()

    def _connection_change(self, device: Device, up: bool, ts: int) -> None:
        if up == device.online:
            return
        device.online = up
        if up:
            device.birth_due = self.born  # DBIRTH at the end of the cycle, with the tree's values then
            return
        # Away: the values the source just marked Bad go with the DDEATH, not as data.
        device.pending = [p for p in device.pending if p[1].good]
        if self.born and device.alive:
            self._flush(device)
            self._send(device.ddeath, encode_ddeath(seq=self.seq, timestamp=ts))
            device.alive = False
        device.birth_due = False

    def _flush(self, device: Device) -> None:
        pending, device.pending = device.pending, []
        metrics = [metric.change(sample) for metric, sample in pending]
        live = self.born and device.alive and self._can_send()
        for start in range(0, len(metrics), MAX_METRICS):
            chunk = metrics[start : start + MAX_METRICS]
            if live:
                self._send_ddata(device, chunk)
            else:
                self._keep(device, chunk)

    def _can_send(self) -> bool:
        client = self._client
        return client is not None and self.connected and client.queued_bytes_pending < PAHO_QUEUE_LIMIT

    def _send_ddata(self, device: Device, metrics: list[Metric]) -> None:
        ts = now_ms()
        payload, metrics = self._encode(lambda ms: encode_ddata(ms, seq=self.seq, timestamp=ts), metrics)
        if payload is None:
            return
        self._send(device.ddata, payload)
        self._unconfirmed.append(_Sent(device, metrics, None))
        self.changes_published += len(metrics)

    def _keep(self, device: Device, metrics: list[Metric]) -> None:
        """Store one DDATA's worth of changes for later, historical (oldest dropped beyond the limit)."""
        backlog = self.backlog
        if backlog is None:
            return
        ts = now_ms()
        body, metrics = self._encode(lambda ms: encode_stored(ms, timestamp=ts), metrics)
        if body is None:
            return
        backlog.put(Message(backlog.next_seq(), device.ddata, body, 0, False, device.name))
        self.changes_stored += len(metrics)

    def _encode(
        self, encode: Callable[[list[Metric]], bytes], metrics: list[Metric]
    ) -> tuple[bytes | None, list[Metric]]:
        """Encode; a value its type cannot carry is left out (and logged once per metric), not the rest."""
        while metrics:
            try:
                return encode(metrics), metrics
            except Unencodable as exc:
                kept = [m for m in metrics if m.name != exc.metric]
                if len(kept) == len(metrics):
                    log.error("Sparkplug: cannot encode a DDATA: %s", exc)
                    return None, []
                self._unencodable_once(exc)
                metrics = kept
        return None, []

    def _unencodable_once(self, exc: SparkplugError) -> None:
        name = exc.metric or ""
        if name not in self._unencodable:
            self._unencodable.add(name)
            log.error("Sparkplug: %s; that value is left out (said once per metric)", exc)

    # --- publishing, fences and the store --------------------------------------------------------

    def _send(self, topic: str, payload: bytes, qos: int = 0) -> int | None:
        client = self._client
        if client is None:
            return None
        try:
            mid = client.publish(topic, payload, qos, False)
        except BrokerError as exc:
            log.error("Sparkplug: %s", exc.reason)
            return None
        self.published += 1
        return mid

    def _send_ndeath(self) -> None:
        if self.bdseq is not None:
            self._ndeath_acked.clear()
            self._ndeath_mid = self._send(
                self.ndeath_topic, encode_ndeath(bdseq=self.bdseq, timestamp=now_ms()), MessageType.NDEATH.qos
            )

    def _fence(self) -> None:
        """Ask the broker to acknowledge what was sent so far (at most one question at a time)."""
        client = self._client
        if self._fence_mid is not None or not self._unconfirmed or client is None or not self.connected:
            return
        try:
            self._fence_mid = client.unsubscribe([FENCE])
        except BrokerError:
            return
        self._fence_covers = len(self._unconfirmed)

    def _confirm(self, count: int) -> None:
        backlog = self.backlog
        confirmed, self._unconfirmed = self._unconfirmed[:count], self._unconfirmed[count:]
        for sent in confirmed:
            if sent.message is not None and backlog is not None:
                backlog.done(sent.message)
                self._replays -= 1
                self.replayed += 1
        if not self._unconfirmed:
            self._fenced.set()

    def _unsubscribed(self, client: MqttClient, mid: int) -> None:
        if client is not self._client or mid != self._fence_mid:
            return
        self._fence_mid = None
        self._confirm(self._fence_covers)
        self._replay()
        self._fence()
        self._commit()

    def _published(self, client: MqttClient, mid: int) -> None:
        """A PUBACK: only the NDEATH goes at QoS 1 (it also fences everything sent before it)."""
        if client is self._client and mid == self._ndeath_mid:
            self._ndeath_acked.set()

    def _replay(self) -> None:
        """Stored messages, oldest first, as historical DDATA of this session: a window at a time."""
        backlog = self.backlog
        if backlog is None or not self.born or not self._can_send() or not backlog:
            return
        room = REPLAY_WINDOW - self._replays
        if room <= 0:
            return
        for msg in backlog.take(room):
            device = self.devices.get(msg.machine or "")
            if device is None:
                log.warning(
                    "Sparkplug: a stored DDATA of %s, which is no device any more, is dropped", msg.machine
                )
                backlog.done(msg)
                continue
            try:
                released = release_stored(msg.payload, device.by_name, seq=self.seq)
            except SparkplugError as exc:
                log.error("Sparkplug: a stored DDATA of %s cannot be read (%s); dropped", device.name, exc)
                backlog.done(msg)
                continue
            if released.dropped:
                log.warning(
                    "Sparkplug: stored values of %s that the births no longer have are dropped: %s",
                    device.name,
                    ", ".join(released.dropped[:5]),
                )
            if released.payload is None:
                backlog.done(msg)
                continue
            self._send(device.ddata, released.payload)
            self._unconfirmed.append(_Sent(device, None, msg))
            self._replays += 1

    # --- from the broker -----------------------------------------------------------------------

    def _incoming(self, msg: Incoming) -> None:
        if self.state_topic is not None and msg.topic == self.state_topic:
            self._state(msg)
        elif self.requests is not None:
            self.requests.handle(msg)

    def _state(self, msg: Incoming) -> None:
        assert self.host is not None and self.requests is not None
        try:
            state = parse_state(msg.payload)
        except SparkplugError as exc:
            self.requests.refuse(exc.kind, f"STATE of {self.config.primary_host_id}", str(exc))
            return
        if not self.host.feed(state):
            return
        host = self.config.primary_host_id
        if self.host.online:
            log.info("Sparkplug: the primary host %s is online", host)
            self._rebirth()
        elif self.born:
            self._leaving = f"the primary host {host} is offline"
            self._session_end.set()
        else:
            log.info("Sparkplug: the primary host %s is offline; storing data until it is back", host)

    # --- outcomes of commands (commands.py) ------------------------------------------------------

    async def _show_variable(self, metric: VariableMetric) -> None:
        async with self._lock:
            self._quiesce()
            device = metric.device
            if self.born and device.alive and self._can_send():
                self._send_ddata(device, [metric.change(metric.node.sample)])
                self._fence()

    async def _show_command(self, device: Device, command: CommandMetric) -> None:
        async with self._lock:
            self._quiesce()
            if self.born and device.alive and self._can_send():
                self._send_ddata(device, command.metrics(now_ms(), birth=False))
                self._fence()

    def _ndata(self, node: NodeMetrics) -> bytes | None:
        ts = now_ms()
        payload, _ = self._encode(lambda ms: encode_ndata(ms, seq=self.seq, timestamp=ts), node.changed(ts))
        return payload

    # --- once a second --------------------------------------------------------------------------

    async def _tick(self) -> None:
        """The node's own metrics as NDATA when they change; reminders while data is being stored."""
        loop = asyncio.get_running_loop()
        last_reminder = loop.time()
        while True:
            await asyncio.sleep(1.0)
            node, backlog = self.node, self.backlog
            if node is not None and self.born:
                payload = self._ndata(node)
                if payload is not None:
                    self._send(self.ndata_topic, payload)
            if not self.born and backlog and loop.time() - last_reminder >= REMIND_EVERY:
                last_reminder = loop.time()
                log.warning(
                    "Sparkplug: %s; %d DDATA messages stored, %d dropped so far",
                    self.state,
                    len(backlog),
                    backlog.dropped_total,
                )
            self._commit()
