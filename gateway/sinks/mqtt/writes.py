"""Write-back: `<topic>/set` requests through the tree's one write path, answers on `<topic>/set/result`.

Everything that can be refused without the controller (unknown topic, oversized,
read-only, writes not enabled, unreadable payload, retained requests) is answered
at once, on the loop, from the paho callback. What is left goes through a
bounded queue per machine to a worker that calls `Machine.write_node`, so that
writes to one machine stay in order, a slow controller holds up only its own
machine, and a flood cannot queue more than `max_pending_writes` per machine.
Refusals are counted and logged with a quota, so junk cannot flood the log either.

Requests act with the machine's MQTT writers' role (`mqtt.writer_role` in the
mapping, else the gateway's `access.mqtt_writer_role`; without users and
without one, the highest role; with users and without one: refused with
BadUserAccessDenied): the broker authenticates the clients, the gateway
authorises the topic. Refusals of a known variable are audited.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Mapping

from gateway.errors import (
    AccessDenied,
    MalformedRequest,
    NotWritable,
    RequestError,
    UnknownVariable,
    WriteError,
)
from gateway.model.context import WriteContext
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.sinks.mqtt.config import MqttConfig, MqttMachineEntry
from gateway.sinks.mqtt.payloads import decode_set, encode_result
from gateway.sinks.mqtt.routes import Route, Routes
from gateway.sinks.mqtt.topics import RESULT, SET, ResponseTopics, result_topic, target_of_set
from gateway.sinks.mqtt_link.client import Incoming
from gateway.sinks.mqtt_link.requests import LogQuota, TooManyWrites, report_roles

log = logging.getLogger(__name__)


def report_writers(tree: VariableTree, routes: Routes, mappings: Mapping[str, MqttMachineEntry]) -> None:
    """Say at start-up, per machine, which `/set` writes and commands the mapping opens to MQTT and the
    role they act with; or that they are refused for want of a role."""

    def opened(machine: Machine) -> tuple[Machine, list[VariableNode], bool]:
        nodes = [r.node for r in routes.by_node.values() if r.writable and r.node.machine is machine]
        mapping = mappings.get(machine.name)
        settings = mapping.mqtt if mapping is not None else None
        return machine, nodes, settings is not None and settings.commands

    report_roles(
        tree,
        map(opened, tree.machines.values()),
        log,
        refused="MQTT: %s: writes and commands enabled in the mapping are refused: they have no role "
        "(mapping: mqtt.writer_role, or the gateway file's access.mqtt_writer_role)",
        acts="MQTT: requests to %s act as %s and may %s",
    )


# (topic to answer on, payload, MQTT v5 correlation data)
Answer = Callable[[str, bytes, "bytes | None"], None]


class ResponseTopicRefused(RequestError):
    """An MQTT 5 response topic the gateway will not publish to (topics.ResponseTopics)."""

    status = "BadRequestNotAllowed"


class _Request:
    __slots__ = ("correlation", "reply", "route", "value")

    def __init__(self, route: Route, value: object, reply: str, correlation: bytes | None) -> None:
        self.route = route
        self.value = value
        self.reply = reply
        self.correlation = correlation


class WriteBack:
    """Turns `/set` messages into tree writes and answers every one of them."""

    def __init__(self, tree: VariableTree, routes: Routes, cfg: MqttConfig, answer: Answer) -> None:
        self.tree = tree
        self.routes = routes
        self.cfg = cfg
        self.answer = answer
        self.queues: dict[str, asyncio.Queue[_Request]] = {
            name: asyncio.Queue(maxsize=cfg.max_pending_writes) for name in tree.machines
        }
        self.received = 0
        self.accepted = 0
        self.refused = 0
        self.refused_response_topics = 0  # requests refused for their response topic (counted in `refused`)
        self._quota = LogQuota()
        self._responses = ResponseTopics(cfg.prefix, cfg.response_topics)

    # --- from paho, on the loop ----------------------------------------------------------------

    def handle(self, msg: Incoming) -> None:
        topic = msg.topic
        if topic in self.routes.by_topic:
            return  # our own value topic that happens to end in /set (a variable named Set)
        target = target_of_set(topic)
        if target is None:
            return
        self.received += 1
        reply = result_topic(target)
        corr = msg.correlation_data
        route = self.routes.by_topic.get(target)
        value: object = msg.payload[:256].decode("utf-8", "replace")  # what was asked, until it is decoded
        try:
            if msg.response_topic is not None:
                refusal = self._responses.refusal(msg.response_topic, f"/{SET}/{RESULT}")
                if refusal is not None:  # answered on the result topic: nothing goes where it asked
                    self.refused_response_topics += 1
                    raise ResponseTopicRefused(refusal)
                reply = msg.response_topic
            if msg.retain:
                raise MalformedRequest(
                    "retained write requests are ignored: publish /set without the retain flag"
                )
            if route is None:
                raise UnknownVariable(f"no variable is published at {target!r}")
            if len(msg.payload) > self.cfg.max_set_payload:
                raise MalformedRequest(
                    f"the payload has {len(msg.payload)} bytes, "
                    f"more than the {self.cfg.max_set_payload} allowed",
                    status="BadRequestTooLarge",
                )
            node = route.node
            if node.internal or not node.definition.writable:
                raise NotWritable(f"{node.full_path} is read-only")
            if not route.writable:
                raise AccessDenied(
                    f"writes over MQTT are not enabled for {node.full_path} (mapping: mqtt.writable: true)"
                )
            access = self.tree.access
            if access.enabled and access.mqtt_role(route.machine) is None:
                raise AccessDenied(
                    f"MQTT writes to {route.machine} have no role while access control is on "
                    "(mapping: mqtt.writer_role, or the gateway file's access.mqtt_writer_role)"
                )
            value = decode_set(msg.payload, node.type)
            queue = self.queues.get(route.machine)
            if queue is None:  # pragma: no cover - every machine has its queue
                raise UnknownVariable(f"no machine {route.machine!r}")
            try:
                queue.put_nowait(_Request(route, value, reply, corr))
            except asyncio.QueueFull:
                raise TooManyWrites(
                    f"{self.cfg.max_pending_writes} writes to {route.machine} are already waiting; try again"
                ) from None
        except RequestError as exc:
            if route is not None:  # known variables only: junk topics are not worth a table row each
                machine = route.node.machine
                ctx = self._context(route.machine)
                machine.audit_write(route.node, route.node.sample.value, value, ctx, exc)
            self._refuse(target, reply, corr, exc)

    def _context(self, machine: str) -> WriteContext:
        return WriteContext("mqtt", user=None, role=self.tree.access.mqtt_role(machine))

    def _refuse(self, target: str, reply: str, corr: bytes | None, exc: RequestError) -> None:
        self.refused += 1
        if self._quota.allow():
            log.info("MQTT write to %s refused: %s (%s)", target[:200], exc.reason[:300], exc.status)
        self.answer(reply, encode_result(exc.reason, exc.status), corr)

    # --- workers ------------------------------------------------------------------------------

    async def worker(self, machine_name: str) -> None:
        """Carry out one machine's queued writes, in order, until cancelled."""
        queue = self.queues[machine_name]
        machine = self.tree.machines[machine_name]
        while True:
            req = await queue.get()
            ctx = self._context(machine_name)
            node = req.route.node
            try:
                await machine.write_node(node, req.value, ctx)
            except RequestError as exc:
                self._refuse(req.route.topic, req.reply, req.correlation, exc)
                continue
            except Exception as exc:  # a bug below must not end write-back for this machine
                log.exception("MQTT write to %s failed unexpectedly", node.full_path)
                self._refuse(
                    req.route.topic, req.reply, req.correlation, WriteError(f"internal error: {exc}")
                )
                continue
            self.accepted += 1
            log.info("MQTT write: %s = %r", node.full_path, req.value)
            self.answer(req.reply, encode_result(), req.correlation)
