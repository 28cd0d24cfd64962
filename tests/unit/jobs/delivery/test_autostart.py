"""Auto-start after delivery: wait for the machine to be ready, select, start, confirm (the tree's writes)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from gateway.config.jobs import AutoStart
from gateway.config.loader import load_mapping
from gateway.errors import ControllerRefused
from gateway.jobs.delivery import autostart
from gateway.jobs.delivery.autostart import AutoStarter
from gateway.jobs.queue.store import Job, JobQueue
from gateway.model.sample import utcnow
from gateway.model.tree import Machine, VariableNode, VariableTree
from tests.waiting import wait_until

MAPPING = """
machine: m1
driver: {endpoint: "opc.tcp://127.0.0.1:4841"}
variables:
  - {path: Machine/State, source: "ns=2;s=st", type: Int16}
  - {path: Control/Select, source: "ns=2;s=sel", type: String, access: readwrite}
  - {path: Control/Start, source: "ns=2;s=go", type: Boolean, access: readwrite}
"""


class Controller:
    """The controller side of writes: records them; Start makes the machine run (State 1)."""

    def __init__(self, machine: Machine, *, starts: bool = True, refuse: int = 0) -> None:
        self.machine = machine
        self.writes: list[tuple[str, Any]] = []
        self.starts = starts
        self.refuse = refuse

    async def write(self, node: VariableNode, raw: Any) -> None:
        if self.refuse:
            self.refuse -= 1
            raise ControllerRefused("BadInvalidState: the machine is busy")
        self.writes.append((node.path, raw))
        if node.path == "Control/Start" and self.starts:
            self.state(1)

    def state(self, value: int) -> None:
        self.machine.ingest(self.machine.nodes["Machine/State"], value, utcnow())


@pytest.fixture
def machine(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Machine:
    monkeypatch.setattr(autostart, "POLL", 0.005)
    path = tmp_path / "m1.yaml"
    path.write_text(MAPPING)
    return VariableTree([load_mapping(path).definition()]).machines["m1"]


@pytest.fixture
def job(tmp_path: Path) -> Job:
    with JobQueue(tmp_path / "q.sqlite3") as q:
        return q.receive("m1", "part.nc", 1, "aa", user="nest")


def auto(**kw: Any) -> AutoStart:
    return AutoStart.model_validate(
        {
            "select": "Control/Select",
            "start": "Control/Start",
            "ready": {"path": "Machine/State", "equals": 0},
            **kw,
        }
    )


async def test_waits_for_ready_then_selects_starts_and_confirms(machine: Machine, job: Job) -> None:
    controller = Controller(machine)
    machine.writer = controller
    controller.state(2)  # paused: not ready
    starter = AutoStarter(machine, auto(), "/DATA/Programs")
    run = asyncio.create_task(starter.run(job, "part.nc"))
    await wait_until(lambda: starter.busy, message="the starter waiting")
    assert controller.writes == []  # not ready: nothing written yet
    controller.state(0)
    assert await run == "started part.nc"
    assert controller.writes == [("Control/Select", "part.nc"), ("Control/Start", True)]
    assert not starter.busy


async def test_select_value_can_be_the_path_or_the_program_name(machine: Machine, job: Job) -> None:
    controller = Controller(machine)
    machine.writer = controller
    controller.state(0)
    await AutoStarter(machine, auto(select_value="path", start=None), "/DATA/Programs/").run(job, "part.nc")
    assert controller.writes == [("Control/Select", "/DATA/Programs/part.nc")]


async def test_not_ready_in_time_and_a_start_that_does_not_take(machine: Machine, job: Job) -> None:
    controller = Controller(machine, starts=False)
    machine.writer = controller
    controller.state(3)
    outcome = await AutoStarter(machine, auto(ready_timeout=0.05), "/P").run(job, "part.nc")
    assert outcome.startswith("not started: Machine/State = 0 did not hold")
    controller.state(0)
    outcome = await AutoStarter(machine, auto(confirm_timeout=0.05), "/P").run(job, "part.nc")
    assert "still holds" in outcome


async def test_a_refusal_is_retried_then_reported(machine: Machine, job: Job) -> None:
    controller = Controller(machine, refuse=1)
    machine.writer = controller
    controller.state(0)
    assert await AutoStarter(machine, auto(), "/P").run(job, "part.nc") == "started part.nc"
    controller = Controller(machine, refuse=99)
    machine.writer = controller
    controller.state(0)
    outcome = await AutoStarter(machine, auto(), "/P").run(job, "part.nc")
    assert outcome.startswith("not started: BadInvalidState") and "BadWriteNotSupported" in outcome
