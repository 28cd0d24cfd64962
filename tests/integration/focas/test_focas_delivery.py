"""Program transfer over FOCAS against the simulator's face: the delivery transport and its program store.

A program goes into the control's folder (a download on a transfer session), is checked by the
folder listing's size or, with `verify: hash`, by uploading it back; `holds` finds it after a
crash; list, get and delete work by name; what the control refuses is a DeliveryError with its code,
permanent where retrying cannot help.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from gateway.errors import DeliveryError, ProgramNotFound
from gateway.transports.base import Program, Progress
from gateway.transports.focas.config import ControllerFocas
from gateway.transports.focas.transport import FocasTransport
from tests.integration.focas.conftest import simulator


def program(tmp_path: Path, name: str, text: bytes) -> Program:
    path = tmp_path / f"{name}.spool"
    path.write_bytes(text)
    return Program(name, path, len(text), hashlib.sha256(text).hexdigest())


@pytest.mark.parametrize("verify", ["size", "hash"])
async def test_a_program_goes_into_the_control_and_is_checked(tmp_path: Path, verify: str) -> None:
    text = b"%\n(PART 7)\n" + b"G1 X10.5 Y20.25 F3000\nG1 X0 Y0\n" * 20_000 + b"M30\n%\n"  # about 1 MB
    async with simulator(tmp_path) as sim:
        assert sim.focas is not None
        config = ControllerFocas(type="focas", host="127.0.0.1", port=sim.focas.port, timeout=5)
        transport = FocasTransport(config, verify=verify)  # type: ignore[arg-type]
        job = program(tmp_path, "part-7.nc", text)
        seen: list[Progress] = []
        where = await transport.deliver(job, seen.append)
        assert where == f"focas://127.0.0.1:{sim.focas.port}//CNC_MEM/USER/PATH1/part-7.nc"
        assert (sim.store / "DATA" / "Programs" / "part-7.nc").read_bytes() == text
        assert seen and seen[-1].sent == len(text)
        assert await transport.holds(job)
        assert not await transport.holds(program(tmp_path, "other.nc", b"%\nM30\n%\n"))
        async with transport.store() as store:
            names = [f.name for f in await store.list()]
            assert "part-7.nc" in names and "demo.nc" in names
            assert await store.size("part-7.nc") == len(text)
            assert await store.get("part-7.nc") == text
            await store.delete("part-7.nc")
            assert await store.size("part-7.nc") is None
            with pytest.raises(ProgramNotFound):
                await store.get("part-7.nc")
            with pytest.raises(ProgramNotFound):
                await store.delete("part-7.nc")


async def test_what_the_control_refuses_is_a_delivery_error(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim:
        assert sim.focas is not None
        config = ControllerFocas(type="focas", host="127.0.0.1", port=sim.focas.port, timeout=5)
        transport = FocasTransport(config)
        with pytest.raises(DeliveryError, match="not a Fanuc file name") as bad:
            await transport.deliver(program(tmp_path, "../escape.nc", b"%\nM30\n%\n"), lambda p: None)
        assert bad.value.permanent
        sim.machine.select_program("demo.nc")
        sim.machine.start()
        async with transport.store() as store:  # the running program cannot be deleted
            with pytest.raises(DeliveryError, match="EW_REJECT") as running:
                await store.delete("demo.nc")
            assert not running.value.permanent
    with pytest.raises(DeliveryError, match=r"cannot reach|connection refused") as gone:
        await transport.deliver(program(tmp_path, "late.nc", b"%\nM30\n%\n"), lambda p: None)
    assert not gone.value.permanent
