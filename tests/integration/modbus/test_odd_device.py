"""The Modbus driver (pymodbus' client) against a device that is not pymodbus (tests/modbus_device.py),
written from the specification, with the answers odd devices give: exceptions on one range, holes in the
register map, a transaction id echoed wrong, an answer from another unit, a short answer, a byte count
that lies, a truncated frame, bytes that are not Modbus, silence, a device that closes or restarts.

In each case: the variables the fault touches turn Bad with a reason that says what happened, the
others stay Good (or come back once the device behaves), and the driver goes on polling.
"""

from __future__ import annotations

import logging
import struct
from typing import Any

import pytest

from gateway.codecs.modbus.address import Table
from gateway.codecs.modbus.frames import Read, Request
from gateway.errors import ControllerRefused, OutOfRange
from gateway.model.tree import Machine
from tests.integration.modbus.conftest import ADMIN, modbus_mapping, polling, sample
from tests.modbus_device import OddDevice
from tests.waiting import wait_until

VARIABLES: list[dict[str, Any]] = [
    {"path": "A", "source": "holding:0", "type": "Int16"},
    {"path": "B", "source": "holding:1:float32", "type": "Float"},  # 1-2
    {"path": "C", "source": "holding:3", "type": "UInt16", "access": "readwrite"},
    {"path": "D", "source": "holding:10:uint32:CDAB", "type": "UInt32"},  # 10-11, behind a hole 4-9
    {"path": "Far", "source": "holding:200", "type": "UInt16"},
    {"path": "In", "source": "input:0:float64:DCBA", "type": "Double"},
    {"path": "Coil", "source": "coil:5", "type": "Boolean", "access": "readwrite"},
    {"path": "Bit", "source": "holding:3.4", "type": "Boolean", "access": "readwrite"},
]


def filled(device: OddDevice) -> OddDevice:
    device.set(Table.HOLDING, 0, [0xFFFF])  # A = -1
    device.set(Table.HOLDING, 1, list(struct.unpack(">2H", struct.pack(">f", 2.5))))
    device.set(Table.HOLDING, 3, [7])
    device.set(Table.HOLDING, 4, [0] * 6)  # no hole: one request reads 0-11
    device.set(Table.HOLDING, 10, [0x5678, 0x1234])  # CDAB: 0x12345678
    device.set(Table.HOLDING, 200, [200])
    little = struct.pack("<d", -0.125)  # DCBA: every byte reversed
    device.set(Table.INPUT, 0, list(struct.unpack(">4H", little)))
    device.set(Table.COIL, 0, [0, 0, 0, 0, 0, 1])
    return device


def good(machine: Machine, *paths: str) -> bool:
    return all(sample(machine, p).good for p in paths)


def reading(request: Request, start: int) -> bool:
    return isinstance(request, Read) and request.function == 3 and request.address == start


async def test_values_in_every_layout_and_one_request_per_range() -> None:
    async with (
        filled(OddDevice()) as device,
        polling(modbus_mapping(device.port, VARIABLES)) as (machine, src),
    ):
        await wait_until(lambda: good(machine, *[v["path"] for v in VARIABLES]), message="all Good")
        assert sample(machine, "A").value == -1
        assert sample(machine, "B").value == 2.5
        assert sample(machine, "C").value == 7
        assert sample(machine, "D").value == 0x12345678
        assert sample(machine, "Far").value == 200
        assert sample(machine, "In").value == -0.125
        assert sample(machine, "Coil").value is True
        assert sample(machine, "Bit").value is False  # 7 = 0b111: bit 4 clear
        # holding 0-11 in one request, 200 in another (past the gap), input, coil: four per cycle
        plan = [
            (r.request.table.value, r.request.start, r.request.count) for g in src.groups for r in g.reads
        ]
        assert plan == [("coil", 5, 1), ("holding", 0, 12), ("holding", 200, 1), ("input", 0, 4)]


async def test_an_exception_on_one_range_marks_only_its_variables_bad(
    caplog: pytest.LogCaptureFixture,
) -> None:
    device = filled(OddDevice())
    device.quirk("exception:4", lambda r: reading(r, 200))  # SERVER DEVICE FAILURE, always
    async with device, polling(modbus_mapping(device.port, VARIABLES)) as (machine, _):
        await wait_until(lambda: sample(machine, "Far").status == "BadDeviceFailure", message="Far Bad")
        assert "SERVER DEVICE FAILURE (exception 4)" in sample(machine, "Far").reason
        await wait_until(lambda: good(machine, "A", "B", "C", "D", "In", "Coil"), message="the rest Good")
        await wait_until(lambda: len(device.reads(3)) > 20, message="a few more cycles")
        said = [r for r in caplog.records if "SERVER DEVICE FAILURE" in r.getMessage()]
        assert len(said) == 1, "said once, not every cycle"
        device.quirks.clear()
        await wait_until(lambda: good(machine, "Far"), message="Far back once the device answers")


async def test_a_hole_in_the_map_isolates_the_bad_address() -> None:
    device = filled(OddDevice())
    del device.tables[Table.HOLDING][4]  # a hole inside the coalesced read 0-11
    variables = [*VARIABLES, {"path": "Gone", "source": "holding:12", "type": "UInt16"}]  # no such register
    async with device, polling(modbus_mapping(device.port, variables)) as (machine, src):
        await wait_until(lambda: good(machine, "A", "B", "C", "D", "Bit"), message="neighbours read alone")
        await wait_until(lambda: sample(machine, "Gone").status == "BadNodeIdUnknown", message="Gone Bad")
        assert "ILLEGAL DATA ADDRESS" in sample(machine, "Gone").reason
        holding = [r.request for g in src.groups for r in g.reads if r.request.table is Table.HOLDING]
        assert all(r.count <= 2 for r in holding if r.start < 200), holding  # read one by one now


@pytest.mark.parametrize(
    ("quirk", "says"),
    [
        ("wrong_tid", "a frame for transaction"),
        ("other_unit", "an answer from unit 2"),
        ("truncated", "no answer within"),
        ("silent", "no answer within"),
        ("garbage", "not Modbus TCP"),
        ("lying_count", "cannot decode"),
        ("close", "closed the connection"),
    ],
)
async def test_framing_faults_end_the_connection_and_it_comes_back(
    quirk: str, says: str, caplog: pytest.LogCaptureFixture
) -> None:
    device = filled(OddDevice())
    device.quirk(quirk, lambda r: reading(r, 200), times=1)
    async with device, polling(modbus_mapping(device.port, VARIABLES)) as (machine, _):
        await wait_until(lambda: says in sample(machine, "Far").reason, message=f"{quirk}: Bad, saying why")
        assert not sample(machine, "Far").good
        assert says in sample(machine, "A").reason  # the connection is not trusted: the whole device
        await wait_until(lambda: good(machine, *[v["path"] for v in VARIABLES]), message=f"{quirk}: back")
        assert device.connections >= 2
    assert not [r for r in caplog.records if r.exc_info or r.levelno >= logging.ERROR], (
        "no error, no traceback"
    )


async def test_a_short_answer_marks_its_range_bad_and_the_stream_goes_on() -> None:
    device = filled(OddDevice())
    device.quirk("short", lambda r: reading(r, 0))
    async with device, polling(modbus_mapping(device.port, VARIABLES)) as (machine, _):
        await wait_until(lambda: sample(machine, "A").status == "BadCommunicationError", message="A Bad")
        assert "answered 11 of 12 registers" in sample(machine, "A").reason
        await wait_until(lambda: good(machine, "Far", "In", "Coil"), message="the rest Good")
        assert device.connections == 1


async def test_writes_their_function_codes_and_the_device_refusals() -> None:
    device = filled(OddDevice())
    async with device, polling(modbus_mapping(device.port, VARIABLES)) as (machine, _):
        await wait_until(lambda: good(machine, "C", "Coil", "Bit"), message="Good")
        await machine.write("C", 4242, ADMIN)
        assert device.get(Table.HOLDING, 3) == [4242]
        assert sample(machine, "C").value == 4242  # read back before the write was answered
        await machine.write("Coil", False, ADMIN)
        assert device.get(Table.COIL, 5) == [0]
        await machine.write("Bit", True, ADMIN)  # read-modify-write: the other bits stay
        assert device.get(Table.HOLDING, 3) == [4242 | 1 << 4]
        assert [s.function for s in device.seen if s.function in (5, 6, 15, 16)] == [6, 5, 6]
        with pytest.raises(OutOfRange):
            await machine.write("C", 70000, ADMIN)
        device.quirk("exception:3", lambda r: not isinstance(r, Read))  # ILLEGAL DATA VALUE
        with pytest.raises(ControllerRefused, match="ILLEGAL DATA VALUE") as refused:
            await machine.write("C", 1, ADMIN)
        assert refused.value.status == "BadOutOfRange"
        assert device.get(Table.HOLDING, 3) == [4242 | 1 << 4]


async def test_write_multiple_uses_functions_15_and_16() -> None:
    device = filled(OddDevice())
    async with device, polling(modbus_mapping(device.port, VARIABLES, write_multiple=True)) as (machine, _):
        await wait_until(lambda: good(machine, "C", "Coil"), message="Good")
        await machine.write("C", 1, ADMIN)
        await machine.write("Coil", False, ADMIN)
        assert [s.function for s in device.seen if s.function in (5, 6, 15, 16)] == [16, 15]


async def test_a_device_restart_turns_everything_bad_then_good_again() -> None:
    device = filled(OddDevice())
    async with device, polling(modbus_mapping(device.port, VARIABLES)) as (machine, _):
        await wait_until(lambda: good(machine, "A", "Far"), message="Good")
        await device.stop()
        await wait_until(lambda: sample(machine, "A").status == "BadNotConnected", message="Bad while down")
        assert not machine.status.is_connected
        device.set(Table.HOLDING, 0, [5])
        await device.start()
        await wait_until(
            lambda: sample(machine, "A").good and sample(machine, "A").value == 5, message="back"
        )
        assert machine.status.reconnects >= 1
