"""Live values for the console's pages: what they watch, looked at once a tick, encoded once per watch.

A page opens a WebSocket (`/api/live`) and says what it shows:

    {"watch": [{"machine": "laser-sim", "paths": null}]}            every variable of a machine
    {"watch": [{"machine": "*", "paths": ["Status/State", …]}]}     these paths of every machine
    {"events": true}                                                 job records and alarm lists too

and gets, at most every `TICK` seconds, what changed among them:

    {"v": [[machine, path, value, status, source time], …]}
    {"job": {…record…}}  {"alarms": {"machine": …, "active": […]}}

Nothing is looked at while no page is open: the console then costs the mirror nothing.
While pages are open, what they watch is looked at once a tick, not at each change: a machine
whose change counter moved since the last tick has its watched variables compared (by sample
identity) with what the pages were last handed, so that a machine changing 400,000 times a
second costs the pages 20 looks at its 500 variables, not 400,000 hub pushes. Only after a tick
in which nothing watched changed does a hub subscription wait for the next change (a doorbell:
a quiet page hears of a change at once, not a tick later), closed again as soon as it rings.
The changes of a tick are split per watch and encoded once per distinct watch, so five browsers
on one page cost one encoding and five socket writes of the same text.
A page whose socket is slow gets its changes merged per variable until it can
take them: memory is bounded by what it watches, never by how long it lags.
A malformed message gets an error reply (`{"error": {"status", "reason"}}`), never a
closed socket or a traceback.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Iterable, Sequence
from itertools import compress
from operator import attrgetter, is_not
from typing import Any

from gateway.errors import MalformedRequest, RequestError, UnknownVariable
from gateway.model.events import Event
from gateway.model.hub import Subscription
from gateway.model.sample import Sample
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.sinks.web.http import plain
from gateway.sinks.web.server import LiveSocket

log = logging.getLogger("gateway.web")

TICK = 0.05  # s: at most 20 updates a second per variable
MAX_PATHS = 20_000
MAX_WATCHES = 64

Change = tuple[VariableNode, Sample]


def row(node: VariableNode, sample: Sample) -> list[Any]:
    """One change as the page gets it: machine, path, value, status, source time (ms since the epoch)."""
    return [node.machine.name, node.path, plain(sample.value), sample.status, _ms(sample)]


def _ms(sample: Sample) -> int | None:
    try:
        return int(sample.source_ts.timestamp() * 1000)
    except (OverflowError, OSError, ValueError):
        return None


_PREFIX: dict[VariableNode, str] = {}  # '["machine","path",' per node, made once
_STATUS: dict[str, str] = {}


def _row_text(node: VariableNode, sample: Sample) -> str:
    """`row()` as JSON text, built by hand: the live path encodes ~10,000 of these a second per page
    shown, and json.dumps over nested lists (with each value made plain first) was most of its cost."""
    prefix = _PREFIX.get(node)
    if prefix is None:
        prefix = _PREFIX[node] = json.dumps([node.machine.name, node.path], ensure_ascii=False)[:-1] + ","
    value = sample.value
    kind = type(value)
    if kind is float and value == value and value not in (_INF, -_INF):
        text = repr(value)
    elif kind is int:
        text = str(value)
    elif kind is bool:
        text = "true" if value else "false"
    else:
        text = json.dumps(plain(value), ensure_ascii=False, separators=(",", ":"))
    status = _STATUS.get(sample.status)
    if status is None:
        status = _STATUS[sample.status] = json.dumps(sample.status)
    ms = _ms(sample)
    return f"{prefix}{text},{status},{'null' if ms is None else ms}]"


_INF = float("inf")


class Watch:
    """What one page shows: whole machines, and single variables."""

    __slots__ = ("key", "machines", "nodes")

    def __init__(self, machines: frozenset[str], nodes: frozenset[VariableNode]) -> None:
        self.machines = machines
        self.nodes = nodes
        self.key = (machines, nodes)

    def wants(self, node: VariableNode) -> bool:
        return node in self.nodes or node.machine.name in self.machines

    def current(self, tree: VariableTree) -> list[Change]:
        out = [(n, n.sample) for n in self.nodes]
        for name in sorted(self.machines):
            out += [(n, n.sample) for n in tree.machines[name].nodes.values() if n not in self.nodes]
        return out


def parse_watch(tree: VariableTree, spec: Any) -> Watch:
    """The watch a page asked for; MalformedRequest or UnknownVariable says what is wrong with it."""
    if not isinstance(spec, list) or len(spec) > MAX_WATCHES:
        raise MalformedRequest(f"watch must be a list of at most {MAX_WATCHES} {{machine, paths}} objects")
    machines: set[str] = set()
    nodes: set[VariableNode] = set()
    for item in spec:
        if not isinstance(item, dict) or not isinstance(item.get("machine"), str):
            raise MalformedRequest('each watch is {"machine": name or "*", "paths": [path, …] or null}')
        name, paths = item["machine"], item.get("paths")
        names = list(tree.machines) if name == "*" else [name]
        if name != "*" and name not in tree.machines:
            raise UnknownVariable(f"no machine {name!r}")
        if paths is None:
            machines.update(names)
            continue
        if not isinstance(paths, list) or not all(isinstance(p, str) for p in paths):
            raise MalformedRequest("paths must be a list of strings, or null for every variable")
        if len(paths) * len(names) + len(nodes) > MAX_PATHS:
            raise MalformedRequest(f"at most {MAX_PATHS} variables may be watched at once")
        unknown = []
        for machine in names:
            table = tree.machines[machine].nodes
            for path in paths:
                node = table.get(path)
                if node is not None:
                    nodes.add(node)
                elif name != "*":  # with "*", a path that some machines lack is fine
                    unknown.append(path)
        if unknown:
            raise UnknownVariable(f"{name} has no variable {', '.join(repr(p) for p in unknown[:5])}")
    return Watch(frozenset(machines), frozenset(nodes))


class Client:
    """One open page: its watch, and what it still has to be sent."""

    def __init__(self, socket: LiveSocket) -> None:
        self.socket = socket
        self.watch: Watch | None = None
        self.events = False
        self.pending: dict[VariableNode, Sample] = {}
        self.extra: list[str] = []  # whole messages (events, replies), in order
        self.ready: str | None = None  # a pre-encoded batch, when nothing else is pending
        self.ready_changes: Sequence[Change] = ()
        self.wake = asyncio.Event()
        self.sent = 0

    def offer(self, changes: Sequence[Change], encoded: str) -> None:
        """This tick's changes for the page, encoded once for every page with the same watch."""
        if not changes:
            return
        if self.ready is None and not self.pending:
            self.ready, self.ready_changes = encoded, changes
        else:  # the page is behind: merge per variable, encode when it can take more
            if self.ready is not None:
                self.pending.update(self.ready_changes)
                self.ready, self.ready_changes = None, ()
            self.pending.update(changes)
        self.wake.set()

    def say(self, message: Any) -> None:
        if len(self.extra) < 1000:
            self.extra.append(json.dumps(plain(message), separators=(",", ":")))
            self.wake.set()

    async def write(self) -> None:
        """Send what is pending, whenever there is some, until the socket closes."""
        while not self.socket.closed:
            await self.wake.wait()
            self.wake.clear()
            extra, self.extra = self.extra, []
            for message in extra:
                if not await self.socket.send(message):
                    return
            text = self.ready
            self.ready, self.ready_changes = None, ()
            if text is None and self.pending:
                pending, self.pending = self.pending, {}
                text = encode(pending.items())
            if text is not None:
                if not await self.socket.send(text):
                    return
                self.sent += 1


def encode(changes: Iterable[Change]) -> str:
    return '{"v":[' + ",".join([_row_text(n, s) for n, s in changes]) + "]}"


class _Scan:
    """One machine's watched variables, and the samples the pages were last handed of them."""

    __slots__ = ("changes", "machine", "nodes", "samples", "whole")

    def __init__(
        self, machine: Machine, whole: bool, nodes: tuple[VariableNode, ...], samples: list[Any]
    ) -> None:
        self.machine = machine
        self.whole = whole  # every variable of the machine, also those added later
        self.nodes = nodes
        self.samples = samples  # per node: the sample last handed out (None: none yet)
        self.changes = machine.changes  # the machine's change counter when last looked at

    def look(self, out: list[Change]) -> None:
        """Append what changed since the last look (by sample identity: every change is a new Sample)."""
        machine = self.machine
        if machine.changes == self.changes:
            return
        self.changes = machine.changes
        if self.whole and len(machine.nodes) != len(self.nodes):
            known = set(self.nodes)
            added = tuple(n for n in machine.nodes.values() if n not in known)
            self.nodes += added
            self.samples += [None] * len(added)
        nodes = self.nodes
        now = list(map(_SAMPLE, nodes))
        out.extend(compress(zip(nodes, now, strict=True), map(is_not, now, self.samples)))
        self.samples = now


_SAMPLE = attrgetter("sample")


class Live:
    """The pages' live updates; `serve()` one socket, `run()` the ticker."""

    def __init__(self, tree: VariableTree, *, tick: float = TICK) -> None:
        self.tree = tree
        self.tick = tick
        self.clients: set[Client] = set()
        self._scans: list[_Scan] = []
        self._watched = asyncio.Event()  # set when some page watches variables

    async def serve(self, socket: LiveSocket) -> None:
        client = Client(socket)
        self.clients.add(client)
        writer = asyncio.ensure_future(client.write())
        writer.set_name("web:live:writer")
        try:
            while True:
                try:
                    text = await socket.receive()
                except RequestError as exc:
                    client.say({"error": {"status": exc.status, "reason": exc.reason}})
                    continue
                if text is None:
                    return
                try:
                    self._message(client, text)
                except RequestError as exc:
                    client.say({"error": {"status": exc.status, "reason": exc.reason}})
        finally:
            self.clients.discard(client)
            self._rewatch()
            writer.cancel()
            await asyncio.gather(writer, return_exceptions=True)

    def _message(self, client: Client, text: str) -> None:
        try:
            message = json.loads(text)
        except RecursionError:
            raise MalformedRequest("malformed JSON: nested too deeply") from None
        except ValueError as exc:
            raise MalformedRequest(f"malformed JSON: {exc}") from None
        if not isinstance(message, dict) or not message.keys() & {"watch", "events"}:
            raise MalformedRequest('expected {"watch": [...]} and/or {"events": true}')
        if "events" in message:
            if not isinstance(message["events"], bool):
                raise MalformedRequest("events must be true or false")
            client.events = message["events"]
        if "watch" in message:
            watch = parse_watch(self.tree, message["watch"])
            client.watch = watch
            client.pending = dict(watch.current(self.tree))
            client.ready, client.ready_changes = None, ()
            self._rewatch()  # with the snapshot, no await between: nothing between the two is lost
            client.wake.set()

    def _rewatch(self) -> None:
        """What the pages watch, per machine, after a page came, went or changed its watch.

        A variable watched before keeps the sample last handed out (a change not yet looked at still
        reaches the pages that watched it); one watched anew starts from its sample now, which the page
        that asked for it got in its snapshot.
        """
        whole: set[str] = set()
        chosen: dict[str, set[VariableNode]] = {}
        for client in self.clients:
            watch = client.watch
            if watch is None:
                continue
            whole.update(watch.machines)
            for node in watch.nodes:
                chosen.setdefault(node.machine.name, set()).add(node)
        before = {scan.machine.name: scan for scan in self._scans}
        scans = []
        for name, machine in self.tree.machines.items():
            if name not in whole and name not in chosen:
                continue
            mine = chosen.get(name, set())
            nodes = tuple(n for n in machine.nodes.values() if name in whole or n in mine)
            old = before.get(name)
            last = dict(zip(old.nodes, old.samples, strict=True)) if old is not None else {}
            scan = _Scan(machine, name in whole, nodes, [last.get(n, n.sample) for n in nodes])
            if old is not None:
                scan.changes = old.changes
            scans.append(scan)
        self._scans = scans
        if scans:
            self._watched.set()

    def changes(self) -> list[Change]:
        """What changed among the watched variables since the last look, per machine."""
        out: list[Change] = []
        for scan in self._scans:
            scan.look(out)
        return out

    def event(self, event: Event) -> None:
        """A job record or an alarm list changed: tell the pages that asked for events."""
        if not any(c.events for c in self.clients):
            return
        if event.channel.startswith("jobs/J") and isinstance(event.payload, dict):
            message: dict[str, Any] = {"job": {"machine": event.machine, **event.payload}}
        elif event.channel == "alarms/active":
            message = {"alarms": {"machine": event.machine, "active": event.payload}}
        else:
            return
        for client in self.clients:
            if client.events:
                client.say(message)

    async def run(self) -> None:
        """Until cancelled: while pages are open, every tick, hand each its share of what changed."""
        rang = False
        while True:
            if not self._scans:  # no page open, or none watching variables (events come by event())
                self._watched.clear()
                await self._watched.wait()
                continue
            batch = self.changes()
            if batch:
                self.deliver(batch)
                rang = False
            elif not rang:
                await self._doorbell()
                rang = True
                continue  # look at once
            else:
                rang = False  # it rang for a variable no page watches: a tick before listening again
            await asyncio.sleep(self.tick)

    async def _doorbell(self) -> None:
        """Wait for the next change anywhere in the tree (at most a second, to look for closed pages).

        A hub subscription only while waiting: a busy machine is looked at once a tick instead."""
        sub: Subscription[VariableNode] = self.tree.hub.subscribe("web:live")
        try:
            async with asyncio.timeout(1.0):
                await sub.next_batch()
        except TimeoutError:
            pass
        finally:
            sub.close()

    def deliver(self, batch: Sequence[Change]) -> None:
        encoded: dict[Any, tuple[list[Change], str]] = {}
        for client in self.clients:
            watch = client.watch
            if watch is None:
                continue
            done = encoded.get(watch.key)
            if done is None:
                wants = watch.wants
                mine = [(n, s) for n, s in batch if wants(n)]
                done = encoded[watch.key] = (mine, encode(mine) if mine else "")
            client.offer(*done)
