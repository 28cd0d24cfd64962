"""The demo's driver against a tree whose controller is a small stand-in for the simulator: it keeps the
machine busy, steps aside for anyone else's command (by any door, or behind the gateway's back), leaves
their alarm alone, and takes the machine back once their program has ended, or after its patience."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from datetime import UTC, datetime
from typing import Any

import pytest

from gateway.cli.demo_driver import DEMO_PROGRAM, DemoDriver
from gateway.commands.runner import install_commands
from gateway.config.mapping import MachineMapping
from gateway.errors import InvalidState
from gateway.model.context import WriteContext
from gateway.model.tree import Machine, VariableNode
from tests.trees import MappedTree
from tests.waiting import wait_until

T0 = datetime(2026, 5, 6, 7, 0, 0, tzinfo=UTC)
IDLE, RUNNING, PAUSED, ALARM = 0, 1, 2, 3
USER = WriteContext("mqtt", None, "operator")


def mapping() -> MachineMapping:
    control = [
        {"path": f"Control/{name}", "source": f"ns=2;s={name}", "type": "Boolean", "access": "readwrite"}
        for name in ("Start", "Stop", "Reset")
    ]
    return MachineMapping.model_validate(
        {
            "machine": "m",
            "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
            "variables": [
                {"path": "Machine/State", "source": "ns=2;s=state", "type": "Int16"},
                {"path": "Program/Name", "source": "ns=2;s=name", "type": "String"},
                {
                    "path": "Control/SelectProgram",
                    "source": "ns=2;s=select",
                    "type": "String",
                    "access": "readwrite",
                },
                {"path": "Feed/Override", "source": "ns=2;s=ovr", "type": "UInt16", "access": "readwrite"},
                *control,
            ],
            "commands": {
                "stop": {
                    "writes": [{"path": "Control/Stop", "value": True}],
                    "done": {"path": "Machine/State", "in": [0, 3]},
                    "timeout": 2,
                },
            },
        }
    )


class Controller:
    """Answers writes as the simulator does: Start runs the selected program, Stop and Reset make it Idle."""

    def __init__(self, machine: Machine) -> None:
        self.machine = machine
        self.writes: list[tuple[str, Any, str]] = []  # (path, value, origin)
        self.state = IDLE
        self.program = ""

    async def write(self, node: VariableNode, raw: Any) -> None:
        if node.path == "Control/Start":
            if self.state != IDLE:
                raise InvalidState("a program is already running")
            self.show(RUNNING)
        elif (
            node.path == "Control/Stop" and self.state in (RUNNING, PAUSED)
        ) or node.path == "Control/Reset":
            self.show(IDLE)
        elif node.path == "Control/SelectProgram":
            self.select(raw)

    def show(self, state: int) -> None:
        self.state = state
        self.machine.ingest(self.machine.nodes["Machine/State"], state, T0)

    def select(self, name: str) -> None:
        self.program = name
        self.machine.ingest(self.machine.nodes["Program/Name"], name, T0)


class Trail:
    """The tree's audit entries' (path or method, origin), as a stand-in for the audit trail."""

    def __init__(self) -> None:
        self.entries: list[tuple[str, str]] = []

    def __call__(self, entry: Any) -> None:
        self.entries.append((entry.target, entry.origin))

    def by(self, origin: str) -> list[str]:
        return [target for target, o in self.entries if o == origin]


@asynccontextmanager
async def running(**options: Any) -> AsyncIterator[tuple[Machine, Controller, DemoDriver, Trail]]:
    tree = MappedTree([mapping()])
    install_commands(tree, tree.mappings)
    machine = tree.machines["m"]
    controller = Controller(machine)
    machine.writer = controller
    machine.status.connected()
    controller.show(IDLE)
    controller.select("")
    trail = Trail()
    tree.audit_sinks.append(trail)
    driver = DemoDriver(machine, **{"settle": 0.05, "tick": 0.01, **options})
    task = asyncio.create_task(driver.run(), name="test:demo-driver")
    try:
        yield machine, controller, driver, trail
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    assert driver._before_write not in tree.write_hooks and driver._audited not in tree.audit_sinks


async def driver_ran_demo(controller: Controller, trail: Trail, starts: int = 1) -> None:
    await wait_until(
        lambda: (
            controller.program == DEMO_PROGRAM
            and controller.state == RUNNING
            and trail.by("demo").count("Control/Start") >= starts
        ),
        timeout=5,
        message=f"the driver to start {DEMO_PROGRAM}",
    )


async def settled(driver: DemoDriver) -> None:
    """Twenty more looks at the machine (several settle periods), in which it would have acted, were it to."""
    seen = driver.cycles
    await wait_until(lambda: driver.cycles >= seen + 20, timeout=5, message="the driver's next looks")


async def test_the_driver_keeps_the_machine_busy_and_resets_its_alarms() -> None:
    async with running() as (_, controller, driver, trail):
        await driver_ran_demo(controller, trail)
        assert trail.by("demo") == ["Control/SelectProgram", "Control/Start"]
        controller.show(IDLE)  # demo.nc ended
        await driver_ran_demo(controller, trail, starts=2)
        controller.show(ALARM)
        await wait_until(lambda: "Control/Reset" in trail.by("demo"), timeout=5, message="the driver's reset")
        assert not driver.aside


async def test_a_stop_by_someone_else_leaves_the_machine_idle_for_them() -> None:
    async with running() as (machine, controller, driver, trail):
        await driver_ran_demo(controller, trail)
        await machine.methods[("Commands", "stop")].call(USER, [])
        assert driver.aside
        await settled(driver)
        assert controller.state == IDLE and trail.by("demo").count("Control/Start") == 1


async def test_aside_the_driver_leaves_their_alarm_and_resumes_when_their_program_has_ended() -> None:
    async with running() as (machine, controller, driver, trail):
        await driver_ran_demo(controller, trail)
        await machine.write("Control/Stop", True, USER)
        await machine.write("Control/SelectProgram", "soft-limit.nc", USER)
        await machine.write("Control/Start", True, USER)
        controller.show(ALARM)  # the program ends in an alarm
        await settled(driver)
        assert driver.aside and driver.theirs and "Control/Reset" not in trail.by("demo")
        await machine.write("Control/Reset", True, USER)
        await driver_ran_demo(controller, trail, starts=2)  # back to Idle: their program has ended
        assert not driver.aside


async def test_a_refused_command_counts_too() -> None:
    """A start refused because the driver's program runs: its sender wants the machine next."""
    async with running() as (machine, controller, driver, trail):
        await driver_ran_demo(controller, trail)
        with pytest.raises(InvalidState):
            await machine.write("Control/Start", True, USER)
        assert driver.aside
        controller.show(IDLE)  # demo.nc ended
        await settled(driver)
        assert controller.state == IDLE and trail.by("demo").count("Control/Start") == 1


async def test_changes_behind_the_gateways_back_count_as_someone_else() -> None:
    async with running() as (_, controller, driver, trail):
        await driver_ran_demo(controller, trail)
        controller.show(IDLE)
        controller.select("other.nc")  # on the controller's own panel, not through the gateway
        await wait_until(lambda: driver.aside, timeout=5, message="the driver to step aside")
        await settled(driver)
        assert controller.program == "other.nc" and controller.state == IDLE
        controller.show(RUNNING)  # started on the panel
        await wait_until(lambda: driver.theirs, timeout=5, message="their program, seen running")
        controller.show(IDLE)  # and ended
        await driver_ran_demo(controller, trail, starts=2)


async def test_a_write_that_is_not_a_command_does_not_disturb_the_driver() -> None:
    async with running() as (machine, controller, driver, trail):
        await driver_ran_demo(controller, trail)
        await machine.write("Feed/Override", 50, USER)
        assert not driver.aside


async def test_after_its_patience_the_driver_takes_an_idle_machine_back() -> None:
    async with running(patience=0.3) as (machine, controller, driver, trail):
        await driver_ran_demo(controller, trail)
        await machine.write("Control/Stop", True, USER)
        assert driver.aside
        await driver_ran_demo(controller, trail, starts=2)
        assert not driver.aside


async def test_a_job_waiting_for_the_machine_keeps_the_driver_from_starting() -> None:
    waiting = True
    async with running(busy=lambda: waiting) as (_, controller, driver, trail):
        await settled(driver)
        assert trail.by("demo") == [] and controller.state == IDLE
        waiting = False
        await driver_ran_demo(controller, trail)
