"""What both MQTT sinks do with a request from the broker before it reaches the tree.

A request (an MQTT `/set` or command, a Sparkplug DCMD) is refused at once when it cannot be
carried out, and the refusals are logged with a quota (`LogQuota`), so that junk cannot flood the
log; what is left waits in a bounded queue per machine (`TooManyWrites` beyond it). Commands carry
a JSON object of their arguments by name (`read_body`, `arguments`), and one machine's commands
run at most `MAX_RUNNING` at once (`carry_out`): a stop must not wait behind a start that is
waiting for its deadline. At start-up, `report_roles` says what the requests may do, and as whom.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Awaitable, Callable, Iterable, Mapping, Sequence
from typing import Any, TypeVar

from gateway.errors import ArgumentsMissing, MalformedRequest, RequestError, TooManyArguments
from gateway.model.methods import Method
from gateway.model.reach import reach
from gateway.model.tree import Machine, VariableNode, VariableTree

log = logging.getLogger("gateway.sinks.mqtt.writes")  # the name log filters knew before the quota moved here

CORRELATION = "correlation_id"
MAX_RUNNING = 4  # commands of one machine carried out at once

_Job = TypeVar("_Job")


class TooManyWrites(RequestError):
    status = "BadTooManyOperations"


class LogQuota:
    """At most `per_minute` lines a minute; the rest are counted and summarised."""

    def __init__(self, per_minute: int = 10) -> None:
        self.per_minute = per_minute
        self._window = 0.0
        self._used = 0
        self._suppressed = 0

    def allow(self) -> bool:
        now = time.monotonic()
        if now - self._window >= 60.0:
            if self._suppressed:
                log.warning(
                    "%d more refused MQTT writes in the last minute (not logged one by one)", self._suppressed
                )
            self._window, self._used, self._suppressed = now, 0, 0
        if self._used < self.per_minute:
            self._used += 1
            return True
        self._suppressed += 1
        return False


def read_body(payload: bytes) -> dict[str, Any]:
    """The request's JSON object (an empty body is `{}`). Raises MalformedRequest with the reason."""
    try:
        text = bytes(payload).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise MalformedRequest(f"the body is not UTF-8 text (byte {exc.start})") from None
    if not text.strip():
        return {}
    try:
        body = json.loads(text)
    except RecursionError:
        raise MalformedRequest("malformed JSON: nested too deeply") from None
    except json.JSONDecodeError as exc:
        raise MalformedRequest(f"malformed JSON: {exc.msg} at character {exc.pos}") from None
    except ValueError as exc:  # json's other refusals (an integer too long to convert, say)
        raise MalformedRequest(f"malformed JSON: {exc}") from None
    if not isinstance(body, dict):
        raise MalformedRequest('expected a JSON object with the arguments by name, e.g. {"name": "part.nc"}')
    return body


def correlation_of(body: Mapping[str, Any]) -> str | int | None:
    value = body.get(CORRELATION)
    if value is None or (isinstance(value, (str, int)) and not isinstance(value, bool)):
        return value
    raise MalformedRequest(f"{CORRELATION} must be text or a number")


def arguments(method: Method, body: Mapping[str, Any]) -> list[Any]:
    """The body's arguments in the method's order (types are checked by the call itself)."""
    names = [a.name for a in method.inputs]
    unknown = sorted(k for k in body if k != CORRELATION and k not in names)
    if unknown:
        takes = ", ".join(names) if names else "no arguments"
        raise TooManyArguments(
            f"{method.name} does not take {', '.join(map(repr, unknown))} (it takes {takes})"
        )
    missing = [n for n in names if n not in body]
    if missing:
        raise ArgumentsMissing(f"{method.name} needs {', '.join(missing)}")
    return [body[n] for n in names]


async def carry_out(
    queue: asyncio.Queue[_Job],
    run: Callable[[_Job], Awaitable[None]],
    name: Callable[[_Job], str],
    at_once: int = MAX_RUNNING,
) -> None:
    """Run the queue's jobs, each as a task of its own, at most `at_once` at a time; until cancelled."""
    slots = asyncio.Semaphore(at_once)

    async def one(job: _Job) -> None:
        try:
            await run(job)
        finally:
            slots.release()

    async with asyncio.TaskGroup() as tg:
        while True:
            job = await queue.get()
            await slots.acquire()
            tg.create_task(one(job), name=name(job))


def report_roles(
    tree: VariableTree,
    opened: Iterable[tuple[Machine, Sequence[VariableNode], bool]],
    log: logging.Logger,
    *,
    refused: str,
    acts: str,
) -> None:
    """Say at start-up, per machine, what the requests the mapping opens (its writable variables, its
    commands) may do and the role they act with; or that they are refused for want of a role.

    `opened`: (machine, variables, commands) per machine; `refused` the line with the machine's name
    (%s), `acts` the line with the machine's name, the role and what it may do (%s each)."""
    access = tree.access
    for machine, nodes, commands in opened:
        objects = {"Commands"} if commands else set()
        if not nodes and not objects:
            continue
        role = access.mqtt_role(machine.name)
        if access.enabled and role is None:
            log.info(refused, machine.name)
            continue
        found = reach(machine, role, variables=nodes, objects=objects, alarms=False)
        log.info(acts, machine.name, role or "no role (access.enabled is false)", found.what())
