"""Command requests: `<prefix>/<machine>/commands/<name>` runs a mapped command, answered on `…/result`.

The body is a JSON object with the command's arguments by name and an optional
`correlation_id`, which the answer repeats: `{"name": "part.nc",
"correlation_id": "c-17"}`; an empty body is `{}`. With MQTT 5, a request's
response topic and correlation data are used, as for writes. Every request gets
exactly one answer:

    {"ok": true,  "status": "Good", "reason": "Machine/State is 1 (Running)", "result": …,
     "duration_ms": 312.5, …}
    {"ok": false, "status": "BadTimeout", "error": "start: no completion within 5 s …", "reason": …,
     "duration_ms": …}

What can be refused without the controller (unknown machine or command, commands
not enabled for the machine, a retained request, an oversized or malformed body,
unknown or missing arguments) is answered at once from the paho callback. The
rest waits in a bounded queue per machine (`max_pending_writes`, like writes) for
that machine's worker, which runs up to `MAX_RUNNING` commands at once (a stop
must not wait behind a start that is waiting for its deadline) through
`Machine.call_method`, the path every sink's calls take (role check, audit).
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from gateway.errors import (
    AccessDenied,
    CallError,
    MalformedRequest,
    RequestError,
)
from gateway.model.context import WriteContext
from gateway.model.methods import Method
from gateway.model.tree import Machine, VariableTree
from gateway.sinks.mqtt.config import MqttConfig, MqttMachineEntry
from gateway.sinks.mqtt.payloads import plain
from gateway.sinks.mqtt.topics import ResponseTopics, clean_segment
from gateway.sinks.mqtt.writes import ResponseTopicRefused
from gateway.sinks.mqtt_link.client import Incoming
from gateway.sinks.mqtt_link.requests import (
    CORRELATION,
    LogQuota,
    TooManyWrites,
    arguments,
    carry_out,
    correlation_of,
    read_body,
)

log = logging.getLogger(__name__)

COMMANDS = "commands"
RESULT = "result"
OBJECT = "Commands"  # the machine methods that are commands (gateway/commands/runner.py)

Answer = Callable[[str, bytes, "bytes | None"], None]
_dumps = json.JSONEncoder(ensure_ascii=False, separators=(",", ":"), allow_nan=False).encode


class UnknownCommand(CallError):
    status = "BadMethodInvalid"


class UnknownMachine(CallError):
    status = "BadNodeIdUnknown"


# --- pure parts ------------------------------------------------------------------------------------


def command_filter(prefix: str) -> str:
    return f"{prefix}/+/{COMMANDS}/+"


def command_target(topic: str, prefix: str) -> tuple[str, str] | None:
    """`cnc/laser-sim/commands/start` → ("laser-sim", "start"); None for any other topic."""
    head = prefix + "/"
    if not topic.startswith(head):
        return None
    levels = topic[len(head) :].split("/")
    if len(levels) != 3 or levels[1] != COMMANDS or not levels[0] or not levels[2]:
        return None
    return levels[0], levels[2]


def encode_reply(
    command: str,
    *,
    duration_ms: float,
    correlation: str | int | None = None,
    result: str | None = None,
    error: RequestError | None = None,
) -> bytes:
    doc: dict[str, Any] = {"ok": error is None, "command": command}
    if error is None:
        doc.update(status="Good", reason=result or "", result=result or "")
    else:
        doc.update(status=error.status, error=error.reason, reason=error.reason)
    doc["duration_ms"] = round(duration_ms, 1)
    if correlation is not None:
        doc[CORRELATION] = correlation
    return _dumps(plain(doc)).encode()


# --- the requests ----------------------------------------------------------------------------------


class _Request:
    __slots__ = ("args", "correlation", "data", "machine", "method", "received", "reply")

    def __init__(
        self,
        machine: Machine,
        method: Method,
        args: list[Any],
        reply: str,
        correlation: str | int | None,
        data: bytes | None,
        received: float,
    ) -> None:
        self.machine = machine
        self.method = method
        self.args = args
        self.reply = reply
        self.correlation = correlation
        self.data = data
        self.received = received


class CommandRequests:
    """Turns command messages into machine method calls and answers every one of them."""

    def __init__(
        self, tree: VariableTree, cfg: MqttConfig, mappings: Mapping[str, MqttMachineEntry], answer: Answer
    ) -> None:
        self.tree = tree
        self.cfg = cfg
        self.mappings = mappings
        self.answer = answer
        self.prefix = cfg.prefix
        self.machines: dict[str, Machine] = {
            clean_segment(name): machine
            for name, machine in tree.machines.items()
            if any(obj == OBJECT for obj, _ in machine.methods)
        }
        self.queues: dict[str, asyncio.Queue[_Request]] = {
            m.name: asyncio.Queue(maxsize=cfg.max_pending_writes) for m in self.machines.values()
        }
        self.received = 0
        self.refused = 0
        self.refused_response_topics = 0  # requests refused for their response topic (counted in `refused`)
        self._quota = LogQuota()
        self._responses = ResponseTopics(cfg.prefix, cfg.response_topics)

    @property
    def filters(self) -> list[str]:
        """What to subscribe to: nothing when no machine has commands."""
        return [command_filter(self.prefix)] if self.machines else []

    # --- from paho, on the loop ----------------------------------------------------------------

    def handle(self, msg: Incoming) -> bool:
        """A command request (answered, now or later): True. Any other message: False."""
        target = command_target(msg.topic, self.prefix)
        if target is None:
            return False
        started = time.monotonic()
        self.received += 1
        segment, name = target
        reply = f"{msg.topic}/{RESULT}"
        correlation: str | int | None = None
        machine = self.machines.get(segment)
        method = machine.methods.get((OBJECT, name)) if machine is not None else None
        try:
            if msg.response_topic is not None:
                refusal = self._responses.refusal(msg.response_topic, f"/{RESULT}")
                if refusal is not None:  # answered on the result topic: nothing goes where it asked
                    self.refused_response_topics += 1
                    raise ResponseTopicRefused(refusal)
                reply = msg.response_topic
            if msg.retain:
                raise MalformedRequest(
                    "retained command requests are ignored: publish them without the retain flag"
                )
            if machine is None:
                raise UnknownMachine(f"no machine {segment!r} has commands")
            if method is None:
                known = ", ".join(n for obj, n in machine.methods if obj == OBJECT)
                raise UnknownCommand(f"{machine.name} has no command {name!r} (it has {known})")
            if len(msg.payload) > self.cfg.max_set_payload:
                raise MalformedRequest(
                    f"the body has {len(msg.payload)} bytes, "
                    f"more than the {self.cfg.max_set_payload} allowed",
                    status="BadRequestTooLarge",
                )
            body = read_body(msg.payload)
            correlation = correlation_of(body)
            mapping = self.mappings.get(machine.name)
            mqtt = mapping.mqtt if mapping is not None else None
            if mqtt is None or not mqtt.commands:
                raise AccessDenied(
                    f"commands over MQTT are not enabled for {machine.name} "
                    "(mapping: mqtt: {commands: true})"
                )
            args = arguments(method, body)
            try:
                self.queues[machine.name].put_nowait(
                    _Request(machine, method, args, reply, correlation, msg.correlation_data, started)
                )
            except asyncio.QueueFull:
                raise TooManyWrites(
                    f"{self.cfg.max_pending_writes} commands for {machine.name} are already waiting; "
                    "try again"
                ) from None
        except RequestError as exc:
            if machine is not None and method is not None:  # known commands only: junk is not worth an entry
                machine.audit_call(method, [], self._context(machine), exc)
            self._refuse(name, reply, msg.correlation_data, correlation, exc, started)
        return True

    def _context(self, machine: Machine) -> WriteContext:
        return WriteContext("mqtt", user=None, role=self.tree.access.mqtt_role(machine.name))

    def _refuse(
        self,
        name: str,
        reply: str,
        data: bytes | None,
        correlation: str | int | None,
        exc: RequestError,
        started: float,
    ) -> None:
        self.refused += 1
        if self._quota.allow():
            log.info("MQTT command %s refused: %s (%s)", name[:100], exc.reason[:300], exc.status)
        payload = encode_reply(
            name, duration_ms=(time.monotonic() - started) * 1000, correlation=correlation, error=exc
        )
        self.answer(reply, payload, data)

    # --- workers ------------------------------------------------------------------------------

    async def worker(self, machine_name: str) -> None:
        """Carry out one machine's queued commands, up to MAX_RUNNING at once, until cancelled."""
        await carry_out(
            self.queues[machine_name], self._run, lambda req: f"mqtt:command:{machine_name}:{req.method.name}"
        )

    async def _run(self, req: _Request) -> None:
        name = req.method.name
        try:
            outputs: Sequence[Any] = await req.machine.call_method(
                req.method, req.args, self._context(req.machine)
            )
        except RequestError as exc:
            self._refuse(name, req.reply, req.data, req.correlation, exc, req.received)
            return
        except Exception as exc:  # a bug below must not end the commands of this machine
            log.exception("MQTT command %s/%s failed unexpectedly", req.machine.name, name)
            self._refuse(
                name, req.reply, req.data, req.correlation, CallError(f"internal error: {exc}"), req.received
            )
            return
        result = str(outputs[0]) if outputs else ""
        log.info("MQTT command %s/%s: %s", req.machine.name, name, result)
        payload = encode_reply(
            name,
            duration_ms=(time.monotonic() - req.received) * 1000,
            correlation=req.correlation,
            result=result,
        )
        self.answer(req.reply, payload, req.data)
