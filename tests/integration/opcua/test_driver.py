"""The OPC UA driver against a real asyncua server over TCP."""

from __future__ import annotations

import asyncio
import logging
import signal
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from datetime import UTC, datetime
from pathlib import Path

import pytest

from gateway.errors import ControllerRefused, ControllerUnavailable
from gateway.model.context import WriteContext
from gateway.model.tree import Machine
from gateway.sources.opcua import client as opcua_client
from gateway.sources.opcua import publish_decode
from gateway.sources.opcua.client import OpcUaSource
from tests.integration.opcua.conftest import NS_URI, SOURCE_TS, Controller, make_machine, source_for
from tests.waiting import free_port, wait_until

CTX = WriteContext("test")


def variables(ctl: Controller) -> list[dict]:
    return [
        {"path": "Axes/X/Position", "source": ctl.source("ActPos"), "type": "Double", "unit": "mm"},
        {"path": "Feed/Override", "source": ctl.source("Override"), "type": "UInt16", "access": "readwrite"},
        {
            "path": "Program/Name",
            "source": ctl.source("ProgramName"),
            "type": "String",
            "access": "readwrite",
        },
        {"path": "ActiveAlarms/Ids", "source": ctl.source("AlarmIds"), "type": "UInt32[]"},
        {"path": "Clock", "source": ctl.source("Clock"), "type": "DateTime", "access": "readwrite"},
        {"path": "Counter", "source": ctl.source("Counter"), "type": "Int32", "access": "readwrite"},
    ]


@asynccontextmanager
async def running(machine: Machine) -> AsyncIterator[tuple[OpcUaSource, asyncio.Task[None]]]:
    async with source_for(machine) as source:
        task = asyncio.create_task(source.run(), name="test-source")
        try:
            yield source, task
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


def all_good(machine: Machine) -> bool:
    return all(node.sample.good for node in machine.mapped)


@pytest.fixture(params=["compiled", "asyncua"])
def decoding(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> tuple[str, list[int]]:
    """Read PublishResponses with the compiled reader or asyncua; the list counts what the reader took."""
    if request.param == "compiled" and publish_decode.compiled is None:
        pytest.skip("the compiled reader is not built here")
    monkeypatch.setattr(publish_decode, "PURE", request.param == "asyncua")
    taken: list[int] = []
    original = publish_decode.decode_fast

    def counting(data: object) -> publish_decode.Publish | None:
        found = original(data)  # type: ignore[arg-type]
        if found is not None:
            taken.append(len(found.changes))
        return found

    monkeypatch.setattr(publish_decode, "decode_fast", counting)
    return str(request.param), taken


async def test_values_flow_into_the_tree_with_source_timestamps(
    controller: Controller, decoding: tuple[str, list[int]]
) -> None:
    machine = make_machine(controller.endpoint, variables(controller))
    async with running(machine):
        await wait_until(lambda: all_good(machine), message="every variable Good")
        assert machine.status.is_connected
        pos = machine.nodes["Axes/X/Position"].sample
        assert pos.value == 12.5
        assert pos.source_ts == SOURCE_TS
        assert machine.nodes["ActiveAlarms/Ids"].sample.value == [3, 7]
        assert machine.nodes["Clock"].sample.value == datetime(2024, 1, 2, 3, 4, 5, tzinfo=UTC)
        assert machine.nodes["Program/Name"].sample.value == "part.nc"

        later = datetime(2024, 5, 6, 7, 9, 0, tzinfo=UTC)
        await controller.set("ActPos", 13.25, later)
        await wait_until(
            lambda: machine.nodes["Axes/X/Position"].sample.value == 13.25, message="new position"
        )
        assert machine.nodes["Axes/X/Position"].sample.source_ts == later
    mode, taken = decoding
    if mode == "compiled":
        assert sum(taken) >= 7, "the compiled reader took the data changes"
    else:
        assert not taken


async def test_a_missing_or_malformed_address_turns_only_that_variable_bad(controller: Controller) -> None:
    extra = [
        {"path": "Ghost", "source": f"ns={controller.ns};s=NoSuchNode", "type": "Double"},
        {"path": "Typo", "source": "ns=2,s=Oops", "type": "Double"},
    ]
    machine = make_machine(controller.endpoint, variables(controller) + extra)
    async with running(machine):
        await wait_until(
            lambda: machine.nodes["Ghost"].sample.status == "BadNodeIdUnknown", message="Ghost bad"
        )
        await wait_until(lambda: machine.nodes["Axes/X/Position"].sample.good, message="others Good")
        assert all(machine.nodes[v["path"]].sample.good for v in variables(controller))
        assert machine.nodes["Typo"].sample.status == "BadNodeIdInvalid"
        assert "ns=2,s=Oops" in machine.nodes["Typo"].sample.reason
        assert "NoSuchNode" in machine.nodes["Ghost"].sample.reason
        assert "Ghost" in machine.status.last_error


async def test_namespace_uri_addresses_resolve_on_the_server(controller: Controller) -> None:
    assert (
        controller.ns != 2
    )  # the fixture registers another namespace first, so the index is not the usual one
    machine = make_machine(
        controller.endpoint,
        [
            {"path": "Position", "source": f"nsu={NS_URI};s=::AsGlobalPV:gAxisX.ActPos", "type": "Double"},
            {"path": "Counter", "source": f"nsu={NS_URI};i=1001", "type": "Int32"},
            {"path": "Elsewhere", "source": "nsu=urn:not-on-this-server;s=X", "type": "Int32"},
        ],
    )
    async with running(machine):
        await wait_until(lambda: machine.nodes["Position"].sample.good, message="Position Good")
        assert machine.nodes["Position"].sample.value == 12.5
        await wait_until(lambda: machine.nodes["Counter"].sample.value == -5, message="Counter")
        assert machine.nodes["Elsewhere"].sample.status == "BadNodeIdUnknown"
        assert "urn:not-on-this-server" in machine.nodes["Elsewhere"].sample.reason


async def test_loss_turns_everything_bad_and_a_restart_recovers(
    controller: Controller, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    machine = make_machine(controller.endpoint, variables(controller))
    async with running(machine) as (_, task):
        await wait_until(lambda: all_good(machine), message="every variable Good")
        await controller.stop()
        await wait_until(
            lambda: all(n.sample.status.startswith("Bad") for n in machine.mapped),
            timeout=3.0,
            message="all Bad",
        )
        assert not machine.status.is_connected
        assert machine.status.state in ("disconnected", "connecting")
        assert machine.status.last_error  # a short human reason
        assert all(
            n.sample.value is not None for n in machine.mapped
        )  # the last value is kept beside the status
        await wait_until(lambda: machine.status.last_error == "connection refused", message="retrying")
        assert not task.done()

        await controller.start()
        await wait_until(lambda: all_good(machine), message="Good again")
        await wait_until(lambda: machine.status.is_connected, message="connected")
        assert machine.status.reconnects == 1
    tracebacks = [r for r in caplog.records if r.exc_info]
    assert tracebacks == []
    lost = [r for r in caplog.records if r.name.startswith("gateway") and "lost connection" in r.getMessage()]
    assert len(lost) == 1 and lost[0].levelno == logging.WARNING


async def test_a_controller_down_at_start_is_retried_until_it_appears(
    caplog: pytest.LogCaptureFixture,
) -> None:
    controller = Controller(free_port())
    await controller.build()  # built but not listening yet
    machine = make_machine(controller.endpoint, variables(controller))
    changes = machine.tree.hub.subscribe("test", every_change=True)
    attempts = 0

    def attempted(n: int) -> bool:
        nonlocal attempts
        attempts += sum(
            1 for node, s in changes.take() if node.path == "Status/State" and s.value == "connecting"
        )
        return attempts >= n

    async with running(machine) as (_, task):
        await wait_until(
            lambda: machine.status.last_error == "connection refused", message="first attempt failed"
        )
        assert all(n.sample.status == "BadNotConnected" for n in machine.mapped)
        await wait_until(lambda: attempted(3), message="further attempts")
        assert not task.done()
        await controller.start()
        try:
            await wait_until(lambda: all_good(machine), message="Good once the controller is up")
            assert machine.status.is_connected
            assert machine.status.reconnects == 0
        finally:
            await controller.stop()
    warnings = [
        r.getMessage()
        for r in caplog.records
        if r.name.startswith("gateway") and r.levelno >= logging.WARNING
    ]
    assert len([w for w in warnings if "cannot connect" in w]) == 1


async def test_write_is_accepted_and_visible_on_the_server(controller: Controller) -> None:
    machine = make_machine(controller.endpoint, variables(controller))
    async with running(machine):
        await wait_until(lambda: machine.status.is_connected, message="connected")
        await machine.write("Feed/Override", 75, CTX)
        assert await controller.get("Override") == 75
        await machine.write("Counter", -12, CTX)
        assert await controller.get("Counter") == -12
        when = datetime(2025, 1, 1, 12, 0, tzinfo=UTC)
        await machine.write("Clock", when.isoformat(), CTX)
        assert (await controller.get("Clock")).replace(tzinfo=UTC) == when
        await wait_until(lambda: machine.nodes["Feed/Override"].sample.value == 75, message="write seen back")


async def test_write_refused_by_the_controller_carries_its_status(controller: Controller) -> None:
    machine = make_machine(controller.endpoint, variables(controller))
    async with running(machine):
        await wait_until(lambda: machine.status.is_connected, message="connected")
        with pytest.raises(ControllerRefused) as refused:
            await machine.write("Program/Name", "other.nc", CTX)  # mapped readwrite, read-only on the server
        assert refused.value.status == "BadUserAccessDenied"  # what asyncua answers for a read-only node
        assert refused.value.status in str(refused.value)
        assert "controller refused" in str(refused.value)
        assert await controller.get("ProgramName") == "part.nc"


async def test_write_while_disconnected_is_controller_unavailable(controller: Controller) -> None:
    machine = make_machine(controller.endpoint, variables(controller))
    async with running(machine):
        await wait_until(lambda: machine.status.is_connected, message="connected")
        await controller.stop()
        await wait_until(lambda: not machine.status.is_connected, message="disconnected")
        with pytest.raises(ControllerUnavailable) as unavailable:
            await machine.write("Feed/Override", 50, CTX)
        assert unavailable.value.status == "BadNotConnected"
        await controller.start()  # the fixture stops it again


async def test_exit_closes_the_session_and_unsets_the_writer(controller: Controller) -> None:
    machine = make_machine(controller.endpoint, variables(controller))
    async with running(machine) as (source, _):
        assert machine.writer is source
        await wait_until(lambda: machine.status.is_connected, message="connected")
        server = controller.server
        assert server is not None
    assert machine.writer is None
    assert not machine.status.is_connected
    await wait_until(lambda: not server.iserver.asyncio_transports, message="server sees the client gone")


@pytest.mark.skipif(not hasattr(signal, "SIGSTOP"), reason="needs POSIX signals to freeze a process")
async def test_a_controller_that_stops_answering_is_caught_by_the_watchdog(root: Path) -> None:
    port = free_port()
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "tests.integration.opcua.controller_process", str(port),
        cwd=root, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL,
    )  # fmt: skip
    try:
        assert process.stdout is not None
        ready = await asyncio.wait_for(process.stdout.readline(), 30)
        ns = int(ready.split()[1])
        machine = make_machine(
            f"opc.tcp://127.0.0.1:{port}/controller",
            [{"path": "Position", "source": f"ns={ns};s=::AsGlobalPV:gAxisX.ActPos", "type": "Double"}],
        )
        async with running(machine):
            await wait_until(lambda: machine.nodes["Position"].sample.good, message="Good")
            process.send_signal(signal.SIGSTOP)  # the TCP connection stays open, nothing answers
            await wait_until(lambda: not machine.nodes["Position"].sample.good, timeout=3.0, message="Bad")
            assert "watchdog" in machine.nodes["Position"].sample.reason
            assert not machine.status.is_connected
            process.send_signal(signal.SIGCONT)
            await wait_until(lambda: machine.nodes["Position"].sample.good, message="Good again")
            assert machine.status.reconnects == 1
    finally:
        if process.returncode is None:
            process.send_signal(signal.SIGCONT)
            process.kill()
        await process.wait()


async def test_a_source_that_falls_behind_is_handed_only_the_newest_value_of_each_variable(
    controller: Controller, decoding: tuple[str, list[int]], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Request-driven flow control (docs/architecture.md, Bounded freshness): one Publish request at the
    controller at a time, the next only once the answer is in the tree. While the gateway does not ask,
    the controller keeps just the newest value of each variable (queue size 1), so a source that fell
    behind by any number of changes gets one change per variable, the latest, and no backlog."""
    gate = asyncio.Event()
    gate.set()
    state = {"in_flight": 0, "most": 0, "held": 0}
    original = opcua_client.publish

    async def gated(session: object, acks: list[object]) -> publish_decode.Publish:
        if not gate.is_set():
            state["held"] += 1
            await gate.wait()
        state["in_flight"] += 1
        state["most"] = max(state["most"], state["in_flight"])
        try:
            return await original(session, acks)  # type: ignore[arg-type]
        finally:
            state["in_flight"] -= 1

    monkeypatch.setattr(opcua_client, "publish", gated)
    machine = make_machine(controller.endpoint, variables(controller), publishing_interval=10)
    counter, position = machine.nodes["Counter"], machine.nodes["Axes/X/Position"]
    seen = machine.tree.hub.subscribe("test", every_change=True)
    async with running(machine):
        await wait_until(lambda: all_good(machine), message="every variable Good")
        gate.clear()  # the gateway falls behind: it asks for nothing more
        await wait_until(lambda: state["held"] == 1, message="the source waiting to ask again")
        server = controller.server
        assert server is not None and server.bserver is not None
        (session,) = server.bserver.clients

        def answers_held() -> bool:  # the controller has changes to send and no request to send them with
            return bool(session.processor._publish_results_subs)

        for n in range(1, 101):
            await controller.set("Counter", n)
            await controller.set("ActPos", float(n))
            if n % 25 == 0:
                await wait_until(answers_held, message="the controller holding changes")
        seen.take()
        gate.set()
        await wait_until(lambda: counter.sample.value == 100, message="the newest Counter")
        await wait_until(lambda: position.sample.value == 100.0, message="the newest position")
        after = [(node, sample.value) for node, sample in seen.take() if node in (counter, position)]
        assert sorted(after, key=lambda c: c[0].path) == [(position, 100.0), (counter, 100)]
    assert state["most"] == 1  # never more than one request at the controller


async def test_more_publish_requests_keep_that_many_at_the_controller_and_lose_nothing(
    controller: Controller, decoding: tuple[str, list[int]], monkeypatch: pytest.MonkeyPatch
) -> None:
    """`publish_requests: 2`: two requests at the controller while it has nothing to send, answers taken
    in order, every variable ending at its newest value."""
    state = {"in_flight": 0, "most": 0}
    original = opcua_client.publish

    async def counted(session: object, acks: list[object]) -> publish_decode.Publish:
        state["in_flight"] += 1
        state["most"] = max(state["most"], state["in_flight"])
        try:
            return await original(session, acks)  # type: ignore[arg-type]
        finally:
            state["in_flight"] -= 1

    monkeypatch.setattr(opcua_client, "publish", counted)
    machine = make_machine(
        controller.endpoint, variables(controller), publishing_interval=10, publish_requests=2
    )
    counter = machine.nodes["Counter"]
    async with running(machine):
        await wait_until(lambda: all_good(machine), message="every variable Good")
        await wait_until(lambda: state["in_flight"] == 2, message="two requests at the controller")
        for n in range(1, 51):
            await controller.set("Counter", n)
        await wait_until(lambda: counter.sample.value == 50, message="the newest Counter")
    assert state["most"] == 2  # never more than asked for
