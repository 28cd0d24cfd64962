"""tests/corpus/focas/controller.yaml served by a fake Fanuc: each answer is a reported error, never a crash.

A session breaker (truncated frames, wrong lengths, junk, the session limit, silence) drops the
session with its reason in Status/LastError, every variable turns Bad and the driver reconnects;
a refused command (EW_BUSY, EW_NUMBER, ...) turns its variable Bad with the controller's reason
while the others stay Good.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.config.loader import load_mapping
from tests.integration.focas.conftest import gateway_config, running
from tests.integration.focas.fake_cnc import FakeCnc
from tests.waiting import wait_until

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "focas" / "controller.yaml"
MACHINE = "fanuc-junk"


def cases() -> list[dict[str, Any]]:
    loaded = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))
    assert isinstance(loaded, list) and loaded
    return loaded


def mapping(port: int, tmp_path: Path) -> Any:
    path = tmp_path / "corpus.yaml"
    path.write_text(
        f"""
machine: {MACHINE}
driver: {{type: focas, host: 127.0.0.1, port: {port}, timeout: 0.5, reconnect: {{initial: 0.1, max: 0.3}}}}
variables:
  - {{path: Machine/Run, source: status.run, type: Int16}}
  - {{path: Macros/M500, source: "#500", type: Double}}
"""
    )
    return load_mapping(path)


@pytest.mark.parametrize("case", cases(), ids=lambda c: c["name"])
async def test_junk_from_a_controller_is_a_reported_error(case: dict[str, Any], tmp_path: Path) -> None:
    fake = FakeCnc(case)
    async with fake.serving() as port, running(gateway_config(tmp_path, mapping(port, tmp_path))) as gw:
        machine = gw.tree.machines[MACHINE]
        if "error" in case:
            fragment = case["error"]
            await wait_until(lambda: fragment in machine.status.last_error, timeout=10,
                             message=f"Status/LastError saying {fragment!r}")  # fmt: skip
            node = gw.tree.find(MACHINE, "Machine/Run")
            await wait_until(lambda: not node.sample.good, message="Bad")
            await wait_until(lambda: fake.connections >= 2, message="a reconnect")
        else:
            bad = case["bad"]
            node = gw.tree.find(MACHINE, bad["path"])
            await wait_until(lambda: node.sample.status == bad["status"], timeout=10, message=bad["status"])
            assert bad["reason"] in node.sample.reason
            other = "Macros/M500" if bad["path"] == "Machine/Run" else "Machine/Run"
            await wait_until(lambda: gw.tree.find(MACHINE, other).sample.good, message=f"{other} Good")
            assert machine.status.is_connected and fake.connections == 1
