"""A receiver connected to the gateway sees the machine cut: positions, block numbers, program, laser."""

from __future__ import annotations

from tests.integration.copydata.conftest import STATE_IDLE, STATE_RUNNING, RigFactory, TcpReceiver, targets
from tests.waiting import wait_until

NESTING = {"name": "nesting", "transport": "tcp-server", "bind": "127.0.0.1", "port": 0, "max_rate": 50}


async def test_positions_and_blocks_follow_the_running_program(make_rig: RigFactory) -> None:
    rig = await make_rig(targets({**NESTING, "connected_id": 100}))
    await rig.connected()
    receiver = await TcpReceiver(rig.emitter()).connect(await rig.server_port())
    try:
        await wait_until(lambda: receiver.got.frames, message="the first frame")
        dwdata, snapshot = receiver.got.frames[0]
        assert dwdata == 2 and snapshot["Status/Connected"] is True
        assert set(snapshot) >= {
            "Axes/X/Position",
            "Axes/Y/Position",
            "Axes/Z/Position",
            "Program/Block",
            "Laser/On",
        }
        await rig.start_program()
        await wait_until(
            lambda: STATE_RUNNING in receiver.got.values("Machine/State"), timeout=10, message="Running"
        )
        await wait_until(lambda: receiver.got.values("Machine/State")[-1] == STATE_IDLE, timeout=30,
                         message="the program to finish")  # fmt: skip
        # The frames followed the program: many positions, the blocks in order, the beam on and off.
        xs, blocks = receiver.got.values("Axes/X/Position"), receiver.got.values("Program/Block")
        assert len(set(xs)) > 10 and len(set(blocks)) > 5
        run = blocks[blocks.index(next(b for b in blocks if b > 0)) :]
        assert run == sorted(run), "block numbers went backwards"
        assert True in receiver.got.values("Laser/On") and receiver.got.latest()["Laser/On"] is False
        assert receiver.got.latest()["Program/Name"] == "demo.nc"
        # and ended where the machine is (the gateway's tree mirrors the simulator)
        paths = (
            "Axes/X/Position",
            "Axes/Y/Position",
            "Axes/Z/Position",
            "Program/Block",
            "Program/PartCount",
        )
        await wait_until(lambda: all(receiver.got.latest().get(p) == rig.value(p) for p in paths),
                         message="the receiver's last values to match the machine")  # fmt: skip
        for axis, path in zip(
            rig.sim.machine.axes, ("Axes/X/Position", "Axes/Y/Position", "Axes/Z/Position"), strict=True
        ):
            assert abs(receiver.got.latest()[path] - axis.actual) < 0.01, path
    finally:
        await receiver.close()


async def test_every_client_gets_its_own_snapshot_and_the_same_stream(make_rig: RigFactory) -> None:
    rig = await make_rig(targets(NESTING))
    await rig.connected()
    port = await rig.server_port()
    first = await TcpReceiver(rig.emitter()).connect(port)
    try:
        await rig.start_program()
        await wait_until(lambda: len(first.got.frames) > 5, message="frames for the first client")
        second = await TcpReceiver(rig.emitter()).connect(port)
        try:
            await wait_until(lambda: second.got.frames, message="the second client's snapshot")
            dwdata, snapshot = second.got.frames[0]
            assert dwdata == 2 and len(snapshot) == len(rig.emitter().encoder.table)  # every variable is Good
            assert rig.emitter().stats()["receivers"] == 2
            await wait_until(lambda: len(second.got.frames) > 5, message="changes for the second client too")
        finally:
            await second.close()
        await wait_until(
            lambda: rig.emitter().stats()["receivers"] == 1, message="the second client to be gone"
        )
        await wait_until(lambda: rig.value("Status/CopydataTargets").endswith("listening, 1 client"),
                         message="Status/CopydataTargets to count one client")  # fmt: skip
    finally:
        await first.close()
