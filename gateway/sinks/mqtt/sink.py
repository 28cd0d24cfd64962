"""The MQTT sink: every machine's variables as topics, with liveness, store-and-forward and write-back.

Flow of one change. QoS 1/2 topics promise every change: the hub keeps their
changes in order (its `ordered` nodes), and each becomes a topic (cached per
variable in `Route`) and a payload, sent straight away when the broker is
connected, nothing is waiting and the window of unacknowledged messages has
room, and otherwise put in the `Backlog`. QoS 1 is encoded here, like QoS 0,
with packet ids from the client (issue 28): the packets of one turn of the loop
go out as one write, and the PUBACKs of one read come back as one call
(`_acked`), which frees the window and pulls the next messages from the backlog.
QoS 2, rare, goes through paho's publish(). QoS 0 topics promise the latest value:
the hub keeps one sample per variable (a newer one replaces the waiting one, and
is counted as coalesced), and the `mqtt:latest` task takes the next chunk of
them only when paho has handed the previous one to the socket. Those go out as
pre-encoded PUBLISH packets, written at once, one write per chunk. So under overload nothing
queues between the source and the socket, and what a subscriber receives stays
fresh (issue 13: the queue used to be paho's, up to 50,000 packets deep).
Broker acknowledgements free the window and pull the next messages from the
backlog, oldest first. When the connection drops, the unacknowledged
messages go back to the front of the backlog; on reconnect they are sent again
(with the DUP flag, and counted: `resent`), then the rest. The session stays
clean: a broker that kept ours would also keep the `/set` writes sent to it
while the gateway was away, and hand them to the machine late. The hot path
never awaits per message.

Liveness: `<prefix>/status` (online, with a last will saying offline) and one
retained status document per machine. `Status/MqttState`, `Status/MqttDropped`
and `Status/MqttCoalesced` show the broker link, the drop count and the QoS 0
changes replaced by a newer value before they were sent to OPC UA as well.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Self

from gateway import __version__
from gateway.codecs.mqtt_publish import FAILURE, qos1_first_byte, remaining_length, topic_head
from gateway.errors import BrokerError, SinkError
from gateway.model.events import EventSubscription
from gateway.model.hub import Change, Subscription
from gateway.model.sample import utcnow
from gateway.model.status import STANDBY_STATUS
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.sinks.base import SinkHealth
from gateway.sinks.mqtt.commands import CommandRequests
from gateway.sinks.mqtt.config import MqttConfig, MqttMachineEntry
from gateway.sinks.mqtt.payloads import encode_event, encode_json, encode_raw
from gateway.sinks.mqtt.routes import Route, Routes
from gateway.sinks.mqtt.status import gateway_offline, gateway_online, machine_payload, status_nodes
from gateway.sinks.mqtt.topics import TopicClash, event_topic, set_filters
from gateway.sinks.mqtt.writes import WriteBack, report_writers
from gateway.sinks.mqtt_link.buffer import Message
from gateway.sinks.mqtt_link.client import Connected, Incoming, MqttClient, Will, default_client_id
from gateway.sinks.mqtt_link.link import (
    REMIND_EVERY,
    STATE_CONNECTED,
    STATE_CONNECTING,
    STATE_DISCONNECTED,
    BrokerLink,
    Wording,
    broker_settings,
)

log = logging.getLogger(__name__)

BACKLOG_FILE = "mqtt-backlog.sqlite3"
YIELD_EVERY = 2000  # changes encoded between turns for the rest of the loop
SHUTDOWN_FLUSH = 1.0  # s allowed on the way out for the broker to acknowledge what is in flight
# QoS 0 variables taken, encoded and written at a time; the rest keep coalescing meanwhile. Large: a take
# happens once per turn of the loop at most (after the source's batch that changed them), so a small chunk
# would cap the rate at chunk x turns/s when the source's decoding makes the turns long.
LATEST_CHUNK = 5000
LOW_WINDOW = 1000  # a Receive Maximum below this is said at connect: it caps QoS 1 at a few thousand/s
PAHO_QUEUE_LIMIT = 50_000  # packets paho may hold for a stuck socket before QoS 0 changes are shed
WORDING = Wording(
    label="MQTT",
    check="check mqtt.username/password and the broker's ACL",
    waiting="messages waiting",
    kept="messages",
    lost="messages",
)


class MqttSink(BrokerLink):
    """Mirrors the variable tree into MQTT topics (implements gateway.sinks.base.Sink)."""

    name = "mqtt"

    def __init__(
        self,
        tree: VariableTree,
        config: MqttConfig,
        state_dir: Path,
        mappings: Mapping[str, MqttMachineEntry],
        *,
        base_dir: Path | None = None,
    ) -> None:
        self.tree = tree
        self.config = config
        self.state_dir = state_dir
        self.started = utcnow()
        # Gateway-owned variables, added now so that every sink (OPC UA too) sees them from the start.
        self._link_nodes: dict[str, VariableNode] = {}
        self._dropped_nodes: dict[str, VariableNode] = {}
        self._coalesced_nodes: dict[str, VariableNode] = {}
        for machine in tree.machines.values():
            self._add_status_variables(machine)
        self.mappings = mappings
        try:
            self.routes = Routes(tree, config, mappings)
        except TopicClash as exc:
            raise SinkError(f"MQTT topics: {exc}") from None
        # Variables whose every change is published (QoS 1/2): kept in order by the hub; the rest coalesce.
        self._ordered: set[VariableNode] = {n for n, r in self.routes.by_node.items() if r.qos}
        self._machine_of: dict[VariableNode, str] = {
            n: n.machine.name for n in tree.nodes()
        }  # coalesced counts
        self._status_nodes = {name: status_nodes(m) for name, m in tree.machines.items()}
        self._status_owner = {n: name for name, nodes in self._status_nodes.items() for n in nodes}
        self._last_status: dict[str, bytes] = {}
        self._dirty: set[str] = set()
        settings = broker_settings(
            config,
            base_dir,
            client_id=config.client_id or default_client_id(),
            max_packet_size=config.max_packet_size,
            will=Will(
                self.routes.status_topic, gateway_offline(__version__, "connection to the gateway lost")
            ),
        )
        super().__init__(settings, config.reconnect, WORDING, log)
        self.writes = WriteBack(tree, self.routes, config, self._answer)
        # <prefix>/<machine>/commands/<name>
        self.commands = CommandRequests(tree, config, mappings, self._answer)
        self.discarded = 0  # QoS 0 changes not sent because the broker was away (QoS 0 promises no more)
        self._client: MqttClient | None = None
        self._sub: Subscription[VariableNode] | None = None
        self._events: EventSubscription | None = None
        self._inflight: dict[int, Message] = {}  # through paho (QoS 2, retained QoS 0), by its message id
        self._acks: dict[int, Message] = {}  # QoS 1 on the packet path, by packet id, until its PUBACK
        self._out: list[bytes] = []  # QoS 1 packets of this turn of the loop, written as one
        self._flush_scheduled = False
        self._heads: dict[str, bytes] = {}  # topic → its encoded head, for messages without a Route
        self._v5 = config.protocol == "5"
        self.resent = 0  # QoS 1 messages sent again (DUP) after the connection dropped before their PUBACK
        self.refused = 0  # QoS 1 messages the broker answered with a failure reason code (MQTT 5)
        self._window = config.max_inflight
        self._online = False
        self._lost = asyncio.Event()
        self._pump_scheduled = False
        self._dropped_reported = 0
        self._served_listed: frozenset[str] = frozenset()  # the machines the last online document listed
        self._coalesced_reported = 0
        self._room = asyncio.Event()  # paho handed everything to the socket: the next QoS 0 chunk may go

    def _add_status_variables(self, machine: Machine) -> None:
        self._link_nodes[machine.name] = machine.add_internal(
            "Status/MqttState", "String", "The gateway's link to the MQTT broker: connected, connecting or "
            "disconnected with the reason", STATE_CONNECTING,
        )  # fmt: skip
        self._dropped_nodes[machine.name] = machine.add_internal(
            "Status/MqttDropped", "UInt64", "Changes of this machine that MQTT store-and-forward had to drop "
            "(the broker was away longer than the buffer holds)", 0,
        )  # fmt: skip
        self._coalesced_nodes[machine.name] = machine.add_internal(
            "Status/MqttCoalesced", "UInt64", "Changes of this machine's QoS 0 topics replaced by a newer "
            "value before they could be sent (the broker or the network took less than the machine changed)",
            0,
        )  # fmt: skip

    @property
    def online(self) -> bool:
        return self._online

    @property
    def in_flight(self) -> int:
        return len(self._inflight) + len(self._acks)

    @property
    def coalesced(self) -> int:
        """QoS 0 changes replaced by a newer value of their variable before they were sent."""
        return self._sub.coalesced if self._sub is not None else 0

    @property
    def socket_queue(self) -> int:
        """Writes paho holds that the socket has not taken yet."""
        return self._client.queued_packets if self._client is not None else 0

    @property
    def settled(self) -> bool:
        """Nothing left to do: every change taken from the hub, sent and acknowledged."""
        sub = self._sub
        return (
            sub is not None and not sub.backlog and not self._inflight and not self._acks and not self.backlog
        )

    # --- lifecycle -----------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        buffer = self.config.buffer
        self._open_backlog(buffer.limit, self.state_dir / BACKLOG_FILE if buffer.persist else None)
        self._client = MqttClient(
            self.settings,
            on_message=self._incoming,
            on_published=self._published,
            on_lost=self._on_lost,
            on_drained=self._room.set,
            on_acked=self._acked,
        )
        # Subscribe before reading the current samples, so no change falls between the two.
        self._sub = self.tree.hub.subscribe(
            self.name,
            ordered=self._ordered,
            limit=max(self.config.buffer.limit, 1000),
            tally=self._machine_of,
        )
        # shard: lease: a machine another shard serves has its alarms and jobs published there; judged as
        # each event is published, so one made on standby is not sent once the machine is served here.
        standby = self.tree.standby
        self._events = self.tree.events.subscribe(self.name, accept=lambda e: e.machine not in standby)
        snapshot = [(n, n.sample) for n in self.tree.nodes() if n.sample.status != "BadWaitingForInitialData"]
        await self._encode(snapshot)
        self._dirty.update(self.tree.machines)
        self._flush_statuses()
        self._commit()
        log.info(
            "MQTT: %d topics under %s/ for %s; broker %s",
            len(self.routes.by_topic), self.config.prefix, ", ".join(self.tree.machines), self.endpoint,
        )  # fmt: skip
        report_writers(self.tree, self.routes, self.mappings)
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        client, backlog = self._client, self.backlog
        try:
            if client is not None and self._online:
                await self._say_goodbye(client)
            elif client is not None:
                client.close()
        finally:
            self._online = False
            if backlog is not None:
                backlog.put_front([*self._inflight.values(), *self._acks.values()])
                self._inflight.clear()
                self._acks.clear()
                self._out.clear()
                self._close_backlog()
            if self._sub is not None:
                self._sub.close()
                self._sub = None
            if self._events is not None:
                self._events.close()
                self._events = None

    async def _say_goodbye(self, client: MqttClient) -> None:
        """Deliver what is waiting (briefly), then say offline, then disconnect cleanly."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + SHUTDOWN_FLUSH
        # Polls for at most SHUTDOWN_FLUSH while stopping: paho's acknowledgements come by callback, with no
        # event to wait for.
        while (self.in_flight or self.backlog) and self._online and loop.time() < deadline:  # noqa: ASYNC110
            await asyncio.sleep(0.02)
        payload = gateway_offline(__version__, "gateway stopped", utcnow())
        self._publish_now(self.routes.status_topic, payload, 1, True, None, True)
        deadline = loop.time() + SHUTDOWN_FLUSH / 2
        while self.in_flight and self._online and loop.time() < deadline:  # noqa: ASYNC110 - as above
            await asyncio.sleep(0.01)
        await client.disconnect()

    def health(self) -> SinkHealth:
        """Ready while the broker connection is up; the queues as the diagnostics show them."""
        return self._health(
            ready=self.state == STATE_CONNECTED,
            in_flight=self.in_flight,
            online=self.online,
            discarded=self.discarded,
            coalesced=self.coalesced,
            socket_queue=self.socket_queue,
            resent=self.resent,
        )

    async def run(self) -> None:
        """Keep the broker connection, mirror the changes, carry out writes; until cancelled."""
        if self._sub is None or self._client is None:
            raise RuntimeError("enter the MQTT sink before running it")
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self._connection(), name="mqtt:connection")
            tg.create_task(self._drain(self._sub), name="mqtt:publish")
            tg.create_task(self._drain_latest(self._sub), name="mqtt:latest")
            if self._events is not None:
                tg.create_task(self._drain_events(self._events), name="mqtt:events")
            tg.create_task(self._tick(), name="mqtt:tick")
            for machine in self.tree.machines:
                tg.create_task(self.writes.worker(machine), name=f"mqtt:writes:{machine}")
            for machine in self.commands.queues:
                tg.create_task(self.commands.worker(machine), name=f"mqtt:commands:{machine}")

    # --- the broker connection ------------------------------------------------------------------

    async def _connection(self) -> None:
        client = self._client
        assert client is not None
        await self._keep_connected(client.connect, self._session)

    async def _session(self, info: Connected) -> bool:
        """Connected: publish until the connection is lost (then the link connects again)."""
        self._on_connected(info)
        await self._lost.wait()
        self._lost.clear()
        return False

    def _on_connected(self, info: Connected) -> None:
        assert self._client is not None and self.backlog is not None
        client = self._client
        self.connects += 1
        self._window = min(self.config.max_inflight, info.receive_maximum or self.config.max_inflight)
        if self._window < self.config.max_inflight and self._window < LOW_WINDOW and self._ordered:
            log.info(
                "MQTT: the broker takes at most %d unacknowledged messages (its Receive Maximum), which "
                "bounds QoS 1 throughput; Mosquitto: raise max_inflight_messages (default 20)",
                self._window,
            )
        self._online = True
        self._set_state(STATE_CONNECTED, "")
        try:
            client.subscribe(set_filters(self.config.prefix, self.routes.depths()), qos=1)
        except BrokerError as exc:
            log.error("MQTT: %s; writes over MQTT will not arrive", exc.reason)
        if self.commands.filters:
            try:
                client.subscribe(self.commands.filters, qos=1)
            except BrokerError as exc:
                log.error("MQTT: %s; command requests over MQTT will not arrive", exc.reason)
        # Liveness first: a dashboard should learn that the gateway is back before the backlog arrives.
        self.backlog.discard_latest(self.routes.status_topic)
        self._publish_now(self.routes.status_topic, self._online_payload(), 1, True, None, True)
        waiting = len(self.backlog)
        self._outage.recovered(
            "MQTT: connected to %s as %s%s",
            self.endpoint,
            self.settings.client_id,
            f"; delivering {waiting} buffered messages" if waiting else "",
        )
        self._pump()
        self._commit()
        self._room.set()

    def _on_lost(self, reason: str) -> None:
        """The connection dropped: what the broker did not acknowledge goes back to the backlog."""
        assert self._client is not None and self.backlog is not None
        self._online = False
        unacked = [*self._inflight.values(), *self._acks.values()]
        self._inflight.clear()
        self._acks.clear()
        self._out.clear()  # not written: their messages are among `unacked`
        self._client.take_back()
        self.backlog.put_front(unacked)
        self._commit()
        self._set_state(STATE_DISCONNECTED, f"connection lost: {reason}")
        log.warning(
            "MQTT: connection to %s lost (%s); keeping %d messages until it is back",
            self.endpoint,
            reason,
            len(self.backlog),
        )
        self._lost.set()
        self._room.set()

    def _set_state(self, state: str, reason: str) -> None:
        """The link's state, also in every machine's Status/MqttState."""
        super()._set_state(state, reason)
        text = state if not reason or state == STATE_CONNECTED else f"{state}: {reason}"
        for name, node in self._link_nodes.items():
            self.tree.machines[name].set_internal(node, text)

    # --- publishing ------------------------------------------------------------------------------

    async def _drain(self, sub: Subscription[VariableNode]) -> None:
        """QoS 1/2 topics: every change, in order, at once (the window and the backlog bound them)."""
        while True:
            batch = await sub.next_ordered()
            await self._encode(batch)
            self._flush_statuses()
            self._commit()

    async def _drain_latest(self, sub: Subscription[VariableNode]) -> None:
        """QoS 0 topics (and the status variables): the latest sample per variable, taken only when
        the socket has taken what went before, so that nothing older waits in a queue."""
        while True:
            await self._wait_room()
            batch = await sub.next_latest(LATEST_CHUNK)
            await self._encode(batch)
            self._flush_statuses()
            self._commit()

    async def _wait_room(self) -> None:
        client = self._client
        assert client is not None
        while self._online and client.queued_packets:
            self._room.clear()
            await self._room.wait()

    async def _drain_events(self, sub: EventSubscription) -> None:
        """Job progress, alarms, feedback: JSON on `<prefix>/<machine>/<channel>` at QoS 1.

        State-like events are retained and only the newest per topic is kept while
        the broker is away; stream events are kept in order like QoS 1 changes.
        """
        prefix = self.config.prefix
        while True:
            for event in await sub.next_batch():
                topic = event_topic(prefix, event.machine, event.channel)
                self._emit(topic, encode_event(event), 1, event.retain, event.machine, event.retain)
            self._commit()

    async def _encode(self, batch: list[Change[VariableNode]]) -> None:
        """Each change to its topic. QoS 0 while connected: into one batch of packets, written at once
        (a retained one waits its turn behind the backlog, which may hold an older value of its topic)."""
        by_node = self.routes.by_node
        emit = self._emit
        backlog = self.backlog
        client = self._client
        packets: list[bytes] | None = [] if self._online and client is not None and client.connected else None
        standby = self.tree.standby  # machines another shard serves (shard: lease): nothing of them here
        count = 0
        for node, sample in batch:
            route = by_node.get(node)
            if route is None:
                route = self._late(node)
                if route is None:
                    continue
            if (standby and route.machine in standby) or sample.status == STANDBY_STATUS:
                continue  # another shard serves the machine (or did when this sample was made)
            payload = encode_raw(sample.value) if route.raw else encode_json(sample, route.suffix)
            field = route.field
            if packets is not None and field and (not route.retain or not backlog):
                packets += (route.first, remaining_length(len(field) + len(payload)), field, payload)
            else:
                emit(route.topic, payload, route.qos, route.retain, route.machine, route.latest_only)
            count += 1
            if count % YIELD_EVERY == 0:
                packets = self._send_packets(packets)
                self._flush_statuses()
                self._commit()
                await asyncio.sleep(0)
        self._send_packets(packets)

    def _send_packets(self, packets: list[bytes] | None) -> list[bytes] | None:
        """Hand a batch of encoded QoS 0 packets to paho as one write; a fresh batch, or None when the
        connection went meanwhile (the rest of the changes then take the `_emit` path)."""
        client = self._client
        if packets is None or client is None:
            return None
        if packets:
            try:
                client.publish_packets(b"".join(packets))
            except BrokerError:  # the connection went while encoding: QoS 0 promises no more
                self.discarded += len(packets) // 4
                return None
        return [] if self._online and client.connected else None

    def _late(self, node: VariableNode) -> Route | None:
        """A node without a route: a status variable (folded into the status document), one kept out
        of MQTT, or one that appeared after start-up."""
        self._machine_of.setdefault(node, node.machine.name)
        owner = self._status_owner.get(node)
        if owner is not None:
            self._dirty.add(owner)
            return None
        if node in self.routes.unrouted:
            if node.internal and node.path.startswith("Status/"):  # a status variable added later
                name = node.machine.name
                self._status_nodes.setdefault(name, []).append(node)
                self._status_owner[node] = name
                self._dirty.add(name)
            return None
        try:
            route = self.routes.add(node)
        except TopicClash as exc:
            log.error("MQTT: %s is not published: %s", node.full_path, exc)
            self.routes.unrouted.add(node)
            return None
        if route is not None and route.qos:
            self._ordered.add(node)  # its next changes are kept in order
        return route

    def _emit(
        self, topic: str, payload: bytes, qos: int, retain: bool, machine: str | None, latest: bool
    ) -> None:
        """Send now if nothing is waiting and the window has room; else keep it in order.

        QoS 0 waits for no acknowledgement, so it is held only to paho's queue, not to the
        window of QoS 1/2 messages awaiting one (`max_inflight`).
        """
        backlog = self.backlog
        assert backlog is not None
        if (
            self._online
            and not backlog
            and (
                len(self._inflight) + len(self._acks) < self._window
                or (
                    qos == 0
                    and self._client is not None
                    and self._client.queued_bytes_pending < PAHO_QUEUE_LIMIT
                )
            )
        ):
            self._publish_now(topic, payload, qos, retain, machine, latest)
            return
        if qos == 0 and not retain:
            if (
                self._online
                and self._client is not None
                and self._client.queued_bytes_pending < PAHO_QUEUE_LIMIT
            ):
                self._publish_now(topic, payload, qos, retain, machine, latest)
            else:
                self.discarded += 1
            return
        backlog.put(Message(backlog.next_seq(), topic, payload, qos, retain, machine, latest))

    def _publish_now(
        self, topic: str, payload: bytes, qos: int, retain: bool, machine: str | None, latest: bool
    ) -> None:
        client, backlog = self._client, self.backlog
        assert client is not None and backlog is not None
        if qos == 1:
            self._send_qos1(Message(backlog.next_seq(), topic, payload, qos, retain, machine, latest))
            return
        try:
            mid = client.publish(topic, payload, qos, retain)
        except BrokerError as exc:  # a topic the broker library rejects; the config checks make this rare
            log.error("MQTT: %s", exc.reason)
            return
        if qos or retain:
            self._inflight[mid] = Message(backlog.next_seq(), topic, payload, qos, retain, machine, latest)

    def _send_qos1(self, msg: Message) -> None:
        """Encode a QoS 1 message with the next packet id into this turn's write; it waits for its PUBACK."""
        client = self._client
        assert client is not None
        head = self._heads.get(msg.topic)
        if head is None:
            try:
                head = topic_head(msg.topic)
            except ValueError as exc:
                log.error("MQTT: cannot publish to %r: %s", msg.topic[:200], exc)
                if msg.stored and self.backlog is not None:
                    self.backlog.done(msg)
                return
            self._heads[msg.topic] = head
        dup = msg.sent
        if dup:
            self.resent += 1
        msg.sent = True
        pid = client.packet_id()
        self._acks[pid] = msg
        first = qos1_first_byte(msg.retain, dup)
        ident = pid.to_bytes(2, "big")
        payload = msg.payload
        if self._v5:  # no properties
            self._out += (first, remaining_length(len(head) + 3 + len(payload)), head, ident, b"\0", payload)
        else:
            self._out += (first, remaining_length(len(head) + 2 + len(payload)), head, ident, payload)
        if not self._flush_scheduled:
            self._flush_scheduled = True
            asyncio.get_running_loop().call_soon(self._flush_out)

    def _flush_out(self) -> None:
        """Write this turn's QoS 1 packets as one (their messages stay in `_acks` until acknowledged)."""
        self._flush_scheduled = False
        out, self._out = self._out, []
        client = self._client
        if not out or client is None or not client.connected:
            return  # dropped meanwhile: `_on_lost` put their messages back in the backlog
        with contextlib.suppress(BrokerError):  # as above
            client.write_packets(b"".join(out))

    def _acked(self, acks: list[tuple[int, int]]) -> None:
        """The client: PUBACKs of QoS 1 packets, all those one read brought."""
        pending, backlog = self._acks, self.backlog
        for pid, reason in acks:
            msg = pending.pop(pid, None)
            if msg is None:
                continue
            if reason >= FAILURE:
                self.refused += 1
            if msg.stored and backlog is not None:
                backlog.done(msg)
        if backlog:
            self._pump()
        self._commit()

    def _published(self, mid: int) -> None:
        """paho: the broker acknowledged `mid` (QoS 1/2), or it was written (QoS 0)."""
        msg = self._inflight.pop(mid, None)
        if msg is not None and msg.stored and self.backlog is not None:
            self.backlog.done(msg)
        if not self._pump_scheduled and self.backlog:
            self._pump_scheduled = True
            asyncio.get_running_loop().call_soon(self._pump_soon)

    def _pump_soon(self) -> None:
        self._pump_scheduled = False
        self._pump()
        self._commit()

    def _pump(self) -> None:
        """Hand the oldest waiting messages to paho, as many as the window allows."""
        backlog, client = self.backlog, self._client
        if not self._online or backlog is None or client is None:
            return
        room = self._window - len(self._inflight) - len(self._acks)
        if room <= 0 or not backlog:
            return
        inflight = self._inflight
        for msg in backlog.take(room):
            if msg.qos == 1:
                self._send_qos1(msg)
                continue
            try:
                mid = client.publish(msg.topic, msg.payload, msg.qos, msg.retain)
            except BrokerError as exc:
                log.error("MQTT: %s", exc.reason)
                backlog.done(msg)
                continue
            if msg.qos or msg.retain:
                inflight[mid] = msg
            else:
                backlog.done(msg)

    def _incoming(self, msg: Incoming) -> None:
        """A message from the broker: a command request, or else a write request."""
        if not self.commands.handle(msg):
            self.writes.handle(msg)

    def _answer(self, topic: str, payload: bytes, correlation: bytes | None) -> None:
        """A write result: sent at once if connected (the asker is waiting now), else dropped."""
        client = self._client
        if not self._online or client is None:
            return
        try:
            client.publish_reply(topic, payload, correlation)
        except BrokerError as exc:
            log.info("MQTT: cannot answer on %s: %s", topic[:200], exc.reason)

    # --- status --------------------------------------------------------------------------------

    def _flush_statuses(self) -> None:
        if not self._dirty:
            return
        dirty, self._dirty = self._dirty, set()
        standby = self.tree.standby
        for name in dirty:
            if name in standby:  # another shard serves it and publishes its status
                continue
            topic = self.routes.machine_status.get(name)
            nodes = self._status_nodes.get(name)
            if topic is None or not nodes:
                continue
            payload = machine_payload(nodes)
            if self._last_status.get(name) != payload:
                self._last_status[name] = payload
                self._emit(topic, payload, 1, True, name, True)

    def _served(self) -> frozenset[str]:
        """The machines this process serves (shard: lease: those it holds; otherwise every machine)."""
        return frozenset(self.tree.machines.keys() - self.tree.standby)

    def _online_payload(self) -> bytes:
        dropped = self.backlog.dropped_total if self.backlog is not None else 0
        self._served_listed = served = self._served()
        machines = [name for name in self.tree.machines if name in served]
        return gateway_online(__version__, self.started, machines, dropped)

    async def _tick(self) -> None:
        """Once a second: drop counts into Status/MqttDropped and the status topic, coalesced counts into
        Status/MqttCoalesced; reminders."""
        loop = asyncio.get_running_loop()
        last_reminder = loop.time()
        while True:
            await asyncio.sleep(1.0)
            backlog = self.backlog
            if backlog is None:
                continue
            coalesced = self.coalesced
            if coalesced != self._coalesced_reported:
                self._coalesced_reported = coalesced
                by_machine = self._sub.coalesced_by if self._sub is not None else {}
                for name, node in self._coalesced_nodes.items():
                    self.tree.machines[name].set_internal(node, by_machine.get(name, 0))
            dropped = backlog.dropped_total != self._dropped_reported
            if dropped:
                self._dropped_reported = backlog.dropped_total
                for name, node in self._dropped_nodes.items():
                    self.tree.machines[name].set_internal(node, backlog.dropped.get(name, 0))
            # shard: lease: the status document lists the machines served here, as leases come and go (a
            # consumer learns which shard's will covers which machines).
            if dropped or self._served() != self._served_listed:
                self._emit(self.routes.status_topic, self._online_payload(), 1, True, None, True)
            if not self._online and backlog and loop.time() - last_reminder >= REMIND_EVERY:
                last_reminder = loop.time()
                log.warning(
                    "MQTT: still no broker; %d messages waiting, %d dropped so far",
                    len(backlog),
                    backlog.dropped_total,
                )
            self._commit()
