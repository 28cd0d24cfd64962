"""The simulated chiller: its register map is the one mappings/chiller-sim.yaml reads, its model reacts to
the laser's heat and to writes, and it refuses what a real chiller refuses."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from gateway.codecs.modbus.address import Table
from gateway.codecs.modbus.frames import ExceptionCode, Read, Refused, WriteBits, WriteRegisters
from gateway.config.loader import load_mapping
from simulator.modbus.chiller import CHILLER_MAP, Chiller

ROOT = Path(__file__).resolve().parents[3]


def test_the_shipped_mapping_reads_every_point_of_the_map_as_the_chiller_lays_it_out() -> None:
    mapping = load_mapping(ROOT / "mappings" / "chiller-sim.yaml", environ={})
    by_field = {}
    for variable in mapping.variables:
        by_field[mapping.driver.field(variable.source, variable.raw_type)] = variable.path  # type: ignore[attr-defined]
    assert len(by_field) == len(CHILLER_MAP)
    for point in CHILLER_MAP:
        assert point.field in by_field, f"{point.name} ({point.source}) is not read by the mapping"
        variable = next(v for v in mapping.variables if v.path == by_field[point.field])
        assert variable.writable == point.writable, point.name


def test_the_model_follows_the_laser_and_the_pump() -> None:
    chiller = Chiller()
    for _ in range(300):
        chiller.step(0.1, laser_watts=4000.0)
    assert chiller.value("Flow") == pytest.approx(400, abs=5)  # 40 l/min in 0.1 l/min
    assert chiller.value("HeatLoad") == pytest.approx(6.3, rel=1e-6)
    assert chiller.value("ReturnTemperature") > chiller.value("SupplyTemperature") + 1  # type: ignore[operator]
    assert chiller.value("PumpRunning") is True and chiller.value("CompressorRunning") is True
    assert chiller.value("StatusWord") == 0b0011
    assert chiller.value("Model") == "LX-CHILL5"
    chiller.image.answer(WriteBits(5, 0, (False,)))  # the pump off: no flow, no cooling
    for _ in range(300):
        chiller.step(0.1, laser_watts=4000.0)
    assert chiller.value("Flow") == 0
    assert chiller.value("PumpRunning") is False and chiller.value("CompressorRunning") is False
    assert chiller.value("HighTemperature") is True  # 30 s of the laser's heat and no cooling


def test_writes_a_chiller_refuses() -> None:
    chiller = Chiller()
    words = list(struct.unpack(">2H", struct.pack(">f", 22.0)))
    chiller.image.answer(WriteRegisters(16, 0, (words[1], words[0])))  # CDAB
    assert chiller.setpoint == 22.0
    with pytest.raises(Refused) as refused:
        too_hot = list(struct.unpack(">2H", struct.pack(">f", 35.0)))
        chiller.image.answer(WriteRegisters(16, 0, (too_hot[1], too_hot[0])))
    assert refused.value.code is ExceptionCode.ILLEGAL_DATA_VALUE
    with pytest.raises(Refused) as refused:  # half a float
        chiller.image.answer(WriteRegisters(6, 1, (0,)))
    assert refused.value.code is ExceptionCode.ILLEGAL_DATA_ADDRESS
    with pytest.raises(Refused) as refused:  # the temperatures are not written
        chiller.image.answer(WriteRegisters(6, 3, (0,)))
    assert refused.value.code is ExceptionCode.ILLEGAL_DATA_ADDRESS
    assert chiller.setpoint == 22.0
    with pytest.raises(Refused):
        chiller.image.answer(Read(3, 0, 5))  # past the four holding registers


def test_the_high_temperature_alarm_latches_until_reset() -> None:
    chiller = Chiller()
    chiller.supply = 30.0
    chiller.image.answer(WriteBits(5, 0, (False,)))  # no cooling
    for _ in range(150):
        chiller.step(0.1, laser_watts=6000.0)
    assert chiller.high_temperature and chiller.value("Alarm") is True
    chiller.image.answer(WriteBits(5, 0, (True,)))
    for _ in range(2000):
        chiller.step(0.1, laser_watts=0.0)
    assert chiller.high_temperature  # latched, though the water is cold again
    chiller.image.answer(WriteBits(5, 1, (True,)))
    chiller.step(0.1, laser_watts=0.0)
    assert not chiller.high_temperature and chiller.value("Alarm") is False
    assert chiller.image.get(Table.COIL, 1) == [0]  # the reset coil reads back as released
