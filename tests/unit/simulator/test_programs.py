"""The sample programs that ship in simulator/programs, and the on-disk store that serves them."""

from __future__ import annotations

from pathlib import Path

import pytest

from simulator.alarms import SOFT_LIMIT
from simulator.errors import ProgramNotFound
from simulator.machine import Machine, MachineState
from simulator.store import DirectoryStore


@pytest.fixture
def store(tmp_path: Path) -> DirectoryStore:
    s = DirectoryStore(tmp_path)
    s.prepare()
    return s


def run(m: Machine, name: str) -> list[tuple[float, float, float]]:
    m.select_program(name)
    m.start()
    seen = []
    while m.state is MachineState.RUNNING:
        m.step(0.05)
        seen.append((m.axes[0].actual, m.axes[1].actual, m.axes[2].actual))
    return seen


def test_prepare_installs_samples_without_overwriting(tmp_path: Path) -> None:
    programs = tmp_path / "DATA" / "Programs"
    programs.mkdir(parents=True)
    (programs / "demo.nc").write_text("M30\n")
    store = DirectoryStore(tmp_path)
    store.prepare()
    assert {"demo.nc", "soft-limit.nc"} <= set(store.names())
    assert store.read("demo.nc") == "M30\n"


def test_read_missing_and_odd_names(store: DirectoryStore) -> None:
    with pytest.raises(ProgramNotFound):
        store.read("nope.nc")
    assert not store.exists("../Programs/demo.nc") and not store.exists("DATA")
    (store.programs / "latin1.nc").write_bytes(b"G0 X1 (\xe9)\n")
    assert "\ufffd" in store.read("latin1.nc")


def test_demo_cuts_within_limits_in_30_to_60_seconds(store: DirectoryStore) -> None:
    m = Machine(store)
    seen = run(m, "demo.nc")
    assert m.state is MachineState.IDLE and m.alarms == []
    assert m.program.part_count == 1 and m.program.progress == 100.0
    assert 30.0 <= m.program.run_time <= 60.0
    assert all(0 <= x <= 3000 and 0 <= y <= 1500 and -5 <= z <= 100 for x, y, z in seen)
    assert len({(round(x), round(y)) for x, y, _ in seen}) > 100  # it really moves around


def test_soft_limit_sample_raises_the_soft_limit_alarm(store: DirectoryStore) -> None:
    m = Machine(store)
    seen = run(m, "soft-limit.nc")
    assert m.state is MachineState.ALARM and [a.id for a in m.alarms] == [SOFT_LIMIT]
    assert "X+" in m.alarms[0].text and max(x for x, _, _ in seen) <= 3000
