"""Running a command against a tree whose controller is a small in-process stand-in: guard, writes,
completion, timeout, a controller that drops while the command waits, and registration as Methods."""

from __future__ import annotations

import asyncio
from datetime import UTC, datetime
from typing import Any

import pytest

from gateway.commands.runner import OUTPUTS, install_commands
from gateway.config.mapping import MachineMapping
from gateway.errors import ConfirmTimeout, InvalidState, OutOfRange, RequestError, TypeMismatch
from gateway.model.context import WriteContext
from gateway.model.tree import Machine, VariableNode
from tests.trees import MappedTree
from tests.waiting import wait_until

T0 = datetime(2026, 5, 6, 7, 0, 0, tzinfo=UTC)
CTX = WriteContext("test", "olga", "operator")
STATES = {0: "Idle", 1: "Running", 2: "Paused", 3: "Alarm"}


def mapping(timeout: float = 2.0) -> MachineMapping:
    return MachineMapping.model_validate(
        {
            "machine": "m",
            "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
            "variables": [
                {"path": "Machine/State", "source": "ns=2;s=state", "type": "Int16"},
                {"path": "Program/Name", "source": "ns=2;s=name", "type": "String"},
                {"path": "Control/Start", "source": "ns=2;s=start", "type": "Boolean", "access": "readwrite"},
                {
                    "path": "Control/Select",
                    "source": "ns=2;s=select",
                    "type": "String",
                    "access": "readwrite",
                },
                {
                    "path": "Feed/Override",
                    "source": "ns=2;s=ovr",
                    "type": "UInt16",
                    "access": "readwrite",
                    "range": {"min": 0, "max": 150},
                },
            ],
            "commands": {
                "start": {
                    "allowed": {"path": "Machine/State", "in": [0], "names": STATES},
                    "writes": [{"path": "Control/Start", "value": True}],
                    "done": {"path": "Machine/State", "not": 0, "names": STATES},
                    "timeout": timeout,
                },
                "select-program": {
                    "arguments": [{"name": "name", "type": "String"}],
                    "writes": [{"path": "Control/Select", "value": "{name}"}],
                    "done": {"path": "Program/Name", "equals": "{name}"},
                    "timeout": timeout,
                },
                "override": {
                    "arguments": [{"name": "percent", "type": "UInt16"}],
                    "writes": [{"path": "Feed/Override", "value": "{percent}"}],
                    "role": "engineer",
                },
            },
        }
    )


class Controller:
    """Answers writes like the simulator does, by reporting the new state a moment later."""

    def __init__(self, machine: Machine) -> None:
        self.machine = machine
        self.writes: list[tuple[str, Any]] = []
        self.start_states = [1]  # what the machine reports after a start, in order ([]: it ignores starts)

    async def write(self, node: VariableNode, raw: Any) -> None:
        self.writes.append((node.path, raw))
        asyncio.get_running_loop().call_soon(self._react, node.path, raw)

    def _react(self, path: str, raw: Any) -> None:
        nodes = self.machine.nodes
        if path == "Control/Start":
            for state in self.start_states:
                self.machine.ingest(nodes["Machine/State"], state, T0)
        elif path == "Control/Select":
            self.machine.ingest(nodes["Program/Name"], raw, T0)


def rig(timeout: float = 2.0) -> tuple[Machine, Controller]:
    tree = MappedTree([mapping(timeout)])
    assert install_commands(tree, tree.mappings) == 3
    machine = tree.machines["m"]
    controller = Controller(machine)
    machine.writer = controller
    machine.ingest(machine.nodes["Machine/State"], 0, T0)
    machine.ingest(machine.nodes["Program/Name"], "", T0)
    return machine, controller


async def call(machine: Machine, name: str, *args: Any) -> Any:
    return await machine.methods[("Commands", name)].call(CTX, list(args))


def test_commands_are_methods_on_the_commands_object_with_typed_arguments() -> None:
    machine, _ = rig()
    method = machine.methods[("Commands", "select-program")]
    assert [(a.name, str(a.type)) for a in method.inputs] == [("name", "String")]
    assert method.outputs == OUTPUTS and method.role == "operator"
    assert machine.methods[("Commands", "override")].role == "engineer"


async def test_start_writes_and_waits_until_the_machine_left_idle() -> None:
    machine, controller = rig()
    result, duration = await call(machine, "start")
    assert result == "Machine/State is 1 (Running)" and duration >= 0
    assert controller.writes == [("Control/Start", True)]


async def test_a_state_passed_through_quickly_still_counts() -> None:
    machine, controller = rig()
    controller.start_states = [3, 0]  # straight into Alarm and back to Idle before the command looks
    result, _ = await call(machine, "start")
    assert result == "Machine/State is 3 (Alarm)"
    assert machine.nodes["Machine/State"].sample.value == 0


async def test_an_argument_goes_into_the_write_and_the_condition() -> None:
    machine, controller = rig()
    result, _ = await call(machine, "select-program", "part.nc")
    assert controller.writes == [("Control/Select", "part.nc")]
    assert result == "Program/Name is 'part.nc'"


async def test_the_guard_refuses_naming_the_state_and_nothing_is_written() -> None:
    machine, controller = rig()
    machine.ingest(machine.nodes["Machine/State"], 3, T0)
    with pytest.raises(InvalidState) as info:
        await call(machine, "start")
    assert (
        info.value.reason
        == "start is not allowed while Machine/State is 3 (Alarm); it needs Machine/State = 0 (Idle)"
    )
    assert controller.writes == []


async def test_no_answer_within_the_timeout_is_bad_timeout_saying_what_it_waited_for() -> None:
    machine, controller = rig(timeout=0.3)
    controller.start_states = []
    with pytest.raises(ConfirmTimeout) as info:
        await call(machine, "start")
    assert info.value.status == "BadTimeout"
    assert (
        "no completion within 0.3 s" in info.value.reason and "Machine/State is 0 (Idle)" in info.value.reason
    )
    assert controller.writes == [("Control/Start", True)]


async def test_a_controller_that_drops_while_waiting_ends_the_command_with_its_status() -> None:
    machine, controller = rig()
    controller.start_states = []
    task = asyncio.create_task(call(machine, "start"))
    await wait_until(lambda: controller.writes, message="the start write")
    machine.invalidate("BadNotConnected", "connection lost")
    with pytest.raises(RequestError) as info:
        await task
    assert info.value.status == "BadNotConnected" and "lost Machine/State" in info.value.reason


async def test_an_unknown_state_refuses_with_its_status() -> None:
    machine, _ = rig()
    machine.invalidate("BadNotConnected", "controller unreachable")
    with pytest.raises(RequestError) as info:
        await call(machine, "start")
    assert info.value.status == "BadNotConnected"


async def test_without_a_condition_the_accepted_writes_complete_the_command() -> None:
    machine, controller = rig()
    result, _ = await call(machine, "override", 80)
    assert result == "written: Feed/Override" and controller.writes == [("Feed/Override", 80)]


async def test_the_write_path_checks_still_apply() -> None:
    machine, controller = rig()
    with pytest.raises(OutOfRange):
        await call(machine, "override", 151)
    with pytest.raises(TypeMismatch):
        await call(machine, "select-program", 5)
    assert controller.writes == []
