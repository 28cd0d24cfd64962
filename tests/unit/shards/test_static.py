"""A static shard (`shard: K/N` or a list): which machines a gateway process loads."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.config.loader import load
from gateway.shards.static import KOfN, parse_k_of_n, select

ROOT = Path(__file__).resolve().parents[3]


def test_k_of_n_parses_and_says_what_to_write() -> None:
    assert parse_k_of_n("2/4") == parse_k_of_n(" 2 / 4 ") == KOfN(2, 4)
    for bad, why in (
        ("two", "write K/N"),
        ("0/4", "between 1 and 4"),
        ("5/4", "between 1 and 4"),
        ("1/0", "between 1"),
    ):
        with pytest.raises(ValueError, match=why):
            parse_k_of_n(bad)


@given(st.sets(st.text(alphabet="abcxyz-0123", min_size=1, max_size=6), max_size=60), st.integers(1, 9))
def test_the_n_shards_cover_the_fleet_once_balanced_within_one(machines: set[str], n: int) -> None:
    parts = [select(sorted(machines), KOfN(k, n)) for k in range(1, n + 1)]
    assert sorted(m for part in parts for m in part) == sorted(machines)
    sizes = [len(p) for p in parts]
    assert max(sizes) - min(sizes) <= 1


def test_a_list_selects_by_name_in_name_order() -> None:
    assert select(["c", "a", "b"], ["b", "c"]) == ["b", "c"]


def gateway_file(tmp_path: Path, shard: str) -> Path:
    path = tmp_path / "gateway.yaml"
    maps = ", ".join(
        str(ROOT / "mappings" / f) for f in ("laser-sim.yaml", "haas-sim.yaml", "fanuc-sim.yaml")
    )
    path.write_text(f"machines: [{maps}]\nshard: {shard}\n")
    return path


def test_a_gateway_file_with_a_shard_loads_only_its_machines(tmp_path: Path) -> None:
    fleet = ["fanuc-sim", "haas-sim", "laser-sim"]  # name order
    seen = []
    for k in (1, 2):
        config = load([gateway_file(tmp_path, f"{k}/2")], environ={})
        seen.append(sorted(m.machine for m in config.machines))  # in the files' order; sorted here
        assert len(config.files) == len(config.machines)
    assert seen == [["fanuc-sim", "laser-sim"], ["haas-sim"]]
    config = load([gateway_file(tmp_path, "[laser-sim]")], environ={})
    assert [m.machine for m in config.machines] == ["laser-sim"]
    with_jobs = {m.machine for m in load([gateway_file(tmp_path, "null")], environ={}).machines if m.jobs}
    # The jobs sections of the others' machines stay, for an inbox on a shared queue (docs/scaling.md).
    assert set(config.jobs_elsewhere) == with_jobs - {"laser-sim"}
    assert not load([gateway_file(tmp_path, "null")], environ={}).jobs_elsewhere
    config = load([gateway_file(tmp_path, "${CNC_SHARD}")], environ={"CNC_SHARD": "2/2"})
    assert [m.machine for m in config.machines] == ["haas-sim"]
    assert sorted(m.machine for m in load([gateway_file(tmp_path, "null")], environ={}).machines) == fleet


def test_check_shows_only_the_shards_machines(tmp_path: Path) -> None:
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-m", "gateway.cli.main", "check", str(gateway_file(tmp_path, "2/2"))],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "haas-sim  [" in proc.stdout and "laser-sim  [" not in proc.stdout
