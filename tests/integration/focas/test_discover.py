"""`cnc-gateway discover focas://…` against the simulator: a mapping that loads and reads every item."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

from gateway.config.loader import load_mapping
from tests.integration.focas.conftest import gateway_config, running, simulator
from tests.waiting import wait_until

BIN = Path(sys.executable).parent


async def test_discover_writes_a_mapping_the_gateway_reads(tmp_path: Path) -> None:
    out = tmp_path / "fanuc-1.yaml"
    async with simulator(tmp_path) as sim:
        assert sim.focas is not None
        port = sim.focas.port
        command = [str(BIN / "cnc-gateway"), "discover", f"focas://127.0.0.1:{port}", "--machine", "fanuc-1"]
        proc = await asyncio.to_thread(
            subprocess.run,
            [*command, "-o", str(out)],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert proc.returncode == 0, proc.stderr
        text = out.read_text()
        assert "a Fanuc 31M G4A1 14.0" in text
        for source in (
            "position.absolute[X]",
            "position.machine[Z]",
            "status.run",
            "alarms.message",
            "program.name",
        ):
            assert source in text
        assert "alarms:\n  source: {type: arrays, ids: ActiveAlarms/Numbers" in text
        mapping = load_mapping(out)
        assert mapping.machine == "fanuc-1" and len(mapping.variables) == 30
        async with running(gateway_config(tmp_path, mapping)) as gw:
            machine = gw.tree.machines["fanuc-1"]
            await wait_until(
                lambda: all(n.sample.good for n in machine.mapped), timeout=10, message="all Good"
            )


def test_discover_says_what_is_wrong_with_the_address() -> None:
    proc = subprocess.run([str(BIN / "cnc-gateway"), "discover", "focas://", "--machine", "x"],
                          capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert proc.returncode == 1 and "is not focas://host" in proc.stderr
    proc = subprocess.run([str(BIN / "cnc-gateway"), "discover", "focas://127.0.0.1:1", "--timeout", "1"],
                          capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert proc.returncode == 1 and "connection refused" in proc.stderr
