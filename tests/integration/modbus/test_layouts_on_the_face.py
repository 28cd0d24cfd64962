"""Every Modbus type in every word and byte order, written through the gateway's write path to the
simulator's Modbus TCP face and read back by polling: the registers on the device are what the order
says (worked out here with struct, not with the gateway's codec), and the value comes back unchanged."""

from __future__ import annotations

import struct
from typing import Any

import pytest

from gateway.codecs.modbus.address import Table
from simulator.modbus import ModbusFace, RegisterImage
from tests.integration.modbus.conftest import ADMIN, modbus_mapping, polling, sample
from tests.waiting import wait_until

KINDS = {  # Modbus type: (struct format, variable type, a value)
    "int16": (">h", "Int16", -12345),
    "uint16": (">H", "UInt16", 54321),
    "int32": (">i", "Int32", -123456789),
    "uint32": (">I", "UInt32", 3_000_000_001),
    "int64": (">q", "Int64", -(2**62) - 12345),
    "uint64": (">Q", "UInt64", 2**64 - 3),
    "float32": (">f", "Float", 123.456),
    "float64": (">d", "Double", -9876.54321),
}
ORDERS = ("ABCD", "CDAB", "BADC", "DCBA")


def registers(data: bytes, order: str) -> list[int]:
    words = [data[i : i + 2] for i in range(0, len(data), 2)]
    if order in ("BADC", "DCBA"):
        words = [w[::-1] for w in words]
    if order in ("CDAB", "DCBA"):
        words.reverse()
    return [int.from_bytes(w, "big") for w in words]


def cases() -> list[tuple[str, str, int, bytes, str, Any]]:
    out = []
    address = 0
    for kind, (fmt, type_name, value) in KINDS.items():
        for order in ORDERS:
            out.append((f"{kind}_{order}", f"holding:{address}:{kind}:{order}", address,
                        struct.pack(fmt, value), type_name, value))  # fmt: skip
            address += 4
    for order in ("ABCD", "BADC"):
        out.append((f"string_{order}", f"holding:{address}:string[4]:{order}", address,
                    b"LX-7".ljust(8, b"\0"), "String", "LX-7"))  # fmt: skip
        address += 4
    return out


CASES = cases()


async def test_every_type_and_order_round_trips_through_the_face() -> None:
    image = RegisterImage(
        holding=200, coils=8, writable=[(Table.HOLDING, a) for a in range(200)] + [(Table.COIL, 3)]
    )
    variables = [{"path": name, "source": source, "type": type_name, "access": "readwrite"}
                 for name, source, _, _, type_name, _ in CASES]  # fmt: skip
    variables += [
        {"path": "Bit", "source": "holding:199.9", "type": "Boolean", "access": "readwrite"},
        {"path": "Coil", "source": "coil:3", "type": "Boolean", "access": "readwrite"},
    ]
    async with (
        ModbusFace(image, port=0) as face,
        polling(modbus_mapping(face.port, variables)) as (machine, src),
    ):
        await wait_until(lambda: all(sample(machine, v["path"]).good for v in variables), message="all Good")
        plan = [
            (r.request.table.value, r.request.start, r.request.count) for g in src.groups for r in g.reads
        ]
        assert plan == [("coil", 3, 1), ("holding", 0, 124), ("holding", 124, 12), ("holding", 199, 1)], plan
        for name, _, address, data, _, value in CASES:
            await machine.write(name, value, ADMIN)
            expected = registers(data, name.split("_")[1])
            assert image.get(Table.HOLDING, address, len(expected)) == expected, name
            written = sample(machine, name).value
            assert written == pytest.approx(value, rel=1e-7) if isinstance(value, float) else written == value
        image.set(Table.HOLDING, 199, [0xFFFF])
        await machine.write("Bit", False, ADMIN)
        assert image.get(Table.HOLDING, 199) == [0xFFFF & ~(1 << 9)]
        await machine.write("Coil", True, ADMIN)
        assert image.get(Table.COIL, 3) == [1]
        # and what the device changes itself comes back by polling, in each layout
        counters = [(name, address) for name, _, address, *_ in CASES if name.startswith("uint32")]
        for name, address in counters:
            image.set(Table.HOLDING, address, registers(struct.pack(">I", 7), name.split("_")[1]))
        await wait_until(lambda: all(sample(machine, n).value == 7 for n, _ in counters),
                         message="the device's own changes, polled")  # fmt: skip
