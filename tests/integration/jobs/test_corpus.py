"""Corpora of broken and real-world G-code through the inbox: what the validator says is what happens.

tests/corpus/gcode/*.nc carry their rules, upload name and expected rejections in
header comments (see tests/unit/jobs/validation/test_validation.py). Each goes through a
real FTP upload to a machine with those rules: accepted ones must arrive on the
controller exactly as the validator passed them, rejected ones must be kept in
rejected/ with every expected rule in the reason file, and none of them may reach
the controller. The shared real-world corpus, where present, goes the same way.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
import yaml

from gateway.config.validation import ValidationRules
from gateway.jobs.queue.store import JobState
from gateway.jobs.validation.pipeline import validate_program
from tests.integration.jobs.conftest import Store, mapping_text
from tests.unit.jobs.validation.test_validation import CASES, REAL_WORLD, header
from tests.waiting import wait_until


def machine_text(name: str, port: int, rules: dict[str, object]) -> str:
    flow = json.dumps(rules or {})  # JSON is YAML
    return mapping_text(name, port, folder=f"/DATA/{name}").replace(
        "validation: {dialect: laser-sim}", f"validation: {flow}"
    )


async def run_corpus(
    store: Store, harness, files: list[tuple[bytes, str, dict[str, object], list[str]]]
) -> None:
    rule_sets: list[str] = []
    for _, _, rules, _ in files:
        key = json.dumps(rules, sort_keys=True)
        if key not in rule_sets:
            rule_sets.append(key)
    machines = [f"c{i}" for i in range(len(rule_sets))]
    for machine in machines:
        (store.root / "DATA" / machine).mkdir()
    mappings = [machine_text(m, store.port, json.loads(k)) for m, k in zip(machines, rule_sets, strict=True)]
    async with harness(mappings) as h:
        expected = []
        for data, name, rules, rejections in files:
            machine = machines[rule_sets.index(json.dumps(rules, sort_keys=True))]
            reply = await h.stor(machine, name, data)
            verdict = validate_program(data, name, ValidationRules.model_validate(rules))
            assert reply.startswith("226 J" if verdict.accepted else "550 J"), (name, reply)
            expected.append((int(reply.split()[1][1:]), machine, name, verdict, rejections))
        for seq, machine, name, verdict, rejections in expected:
            if verdict.accepted:
                await h.wait_state(seq, JobState.DELIVERED)
                assert (store.root / "DATA" / machine / name).read_bytes() == verdict.program
                continue
            job = h.job(seq)
            assert job.state is JobState.REJECTED, (name, job)
            reason = Path(f"{h.state / 'rejected' / f'{job.id}-{name}'}.reason").read_text()
            for rule in {r.split()[0] for r in rejections}:
                assert f"[{rule}]" in reason, (name, rule, reason)
            there = store.root / "DATA" / machine / name  # another corpus file may share the name
            assert not there.exists() or there.read_bytes() != files[seq - 1][0], name
        await wait_until(
            lambda: h.queue.count(states=(JobState.QUEUED, JobState.SENDING)) == 0, message="idle queue"
        )


async def test_the_project_corpus_through_the_inbox(store: Store, harness) -> None:
    files = []
    for path in CASES:
        expect, rules, name = header(path)
        rejections = [] if expect == ["accepted"] else expect
        files.append((path.read_bytes(), name, rules, rejections))
    assert len(files) >= 20
    await run_corpus(store, harness, files)


@pytest.mark.skipif(not REAL_WORLD.is_dir(), reason=f"{REAL_WORLD} (the shared real-world corpus) is missing")
@pytest.mark.parametrize("dialect", ["generic", "linuxcnc"])
async def test_the_real_world_corpus_through_the_inbox(store: Store, harness, dialect: str) -> None:
    files = []
    for path in sorted(REAL_WORLD.iterdir()):
        if path.suffix == ".md":
            continue
        data = path.read_bytes()
        verdict = validate_program(data, path.name, ValidationRules.for_dialect(dialect))
        files.append((data, path.name, {"dialect": dialect}, [f"{r.rule} -" for r in verdict.rejections]))
    assert files
    await run_corpus(store, harness, files)
    await asyncio.sleep(0)


def test_headers_are_yaml() -> None:  # the corpus headers this module relies on
    assert yaml.safe_load("{dialect: fanuc}") == {"dialect": "fanuc"}
