"""The chiller that cools the laser source: its model, and its Modbus register map.

The map mixes word orders on purpose, as real auxiliaries do (the commonest source of wrong values):
the supply temperature is a big-endian float (ABCD), the return temperature has its words swapped
(CDAB), the heat load its bytes swapped (BADC), the run-time counter is little-endian (DCBA). The
setpoint is writable (FC 16, both registers; 10-30 degC, else ILLEGAL DATA VALUE), the pump is a
writable coil, an alarm reset coil clears the latched alarm, and the alarm is a discrete input and a
bit of the status word. mappings/chiller-sim.yaml reads every point; the addresses below are in the
mapping's notation and go through the gateway's own parser, so the two cannot drift apart unnoticed
(tests/unit/simulator/test_chiller.py loads the mapping against this map).

The heat it removes is the laser's: 1.5 W of waste heat per optical watt, plus 300 W of its own.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from gateway.codecs.modbus.address import Field, Table, parse_address, resolve
from gateway.codecs.modbus.frames import ExceptionCode, Refused
from gateway.codecs.modbus.layout import decode, encode
from simulator.modbus.image import RegisterImage

SETPOINT_RANGE = (10.0, 30.0)
FLOW_NOMINAL = 40.0  # l/min with the pump on
TAU_SUPPLY = 20.0  # s
TAU_FLOW = 2.0  # s
HIGH_TEMP_DELAY = 10.0  # s above the band before the alarm latches
LOW_FLOW = 10.0  # l/min
MODEL_NAME = "LX-CHILL5"


@dataclass(frozen=True, slots=True)
class Point:
    name: str
    source: str  # as the mapping writes it
    type: str  # the gateway type the mapping gives it
    writable: bool = False

    @property
    def field(self) -> Field:
        return resolve(parse_address(self.source), self.type)


CHILLER_MAP: tuple[Point, ...] = (
    Point("SupplyTemperature", "input:0:float32:ABCD", "Float"),
    Point("ReturnTemperature", "input:2:float32:CDAB", "Float"),
    Point("Flow", "input:4:uint16", "UInt16"),  # 0.1 l/min
    Point("StatusWord", "input:5:uint16", "UInt16"),
    Point("PumpRunning", "input:5.0", "Boolean"),
    Point("CompressorRunning", "input:5.1", "Boolean"),
    Point("HighTemperature", "input:5.2", "Boolean"),
    Point("LowFlow", "input:5.3", "Boolean"),
    Point("RunSeconds", "input:6:uint32:DCBA", "UInt32"),
    Point("Model", "input:8:string[6]", "String"),
    Point("HeatLoad", "input:14:float32:BADC", "Float"),  # kW
    Point("Setpoint", "holding:0:float32:CDAB", "Float", writable=True),
    Point("HighTemperatureBand", "holding:2:int16", "Int16", writable=True),  # 0.1 K
    Point("PumpOn", "coil:0", "Boolean", writable=True),
    Point("AlarmReset", "coil:1", "Boolean", writable=True),
    Point("Alarm", "discrete:0", "Boolean"),
)
_FIELDS = {p.name: p.field for p in CHILLER_MAP}


class Chiller:
    """The model: `step(dt, laser_watts)` each tick, `render()` into the image the face serves."""

    def __init__(self, ambient: float = 24.0) -> None:
        self.ambient = ambient
        self.setpoint = 20.0
        self.band = 25  # 0.1 K above the setpoint before the high-temperature alarm
        self.pump_on = True
        self.supply = self.setpoint + 0.5  # from standby: near the setpoint
        self.flow = 0.0
        self.heat_kw = 0.3
        self.run_seconds = 0.0
        self.high_temperature = False
        self.low_flow = False
        self._above_for = 0.0
        self._time = 0.0
        self.image = RegisterImage(
            coils=2,
            discrete=1,
            inputs=20,
            holding=4,
            writable=[(Table.HOLDING, a) for a in range(3)] + [(Table.COIL, 0), (Table.COIL, 1)],
            on_write=self._written,
        )
        self.render()

    @property
    def compressor(self) -> bool:
        return self.pump_on and self.flow > LOW_FLOW

    @property
    def return_temperature(self) -> float:
        kg_per_s = max(self.flow, 0.5) / 60.0
        return self.supply + self.heat_kw * 1000.0 / (kg_per_s * 4186.0)

    def step(self, dt: float, laser_watts: float) -> None:
        self._time += dt
        self.heat_kw = (300.0 + 1.5 * laser_watts) / 1000.0
        ripple = 0.4 * math.sin(self._time * 0.7)  # a real pump's flow is never quite still
        target_flow = FLOW_NOMINAL + ripple if self.pump_on else 0.0
        self.flow += (target_flow - self.flow) * (1 - math.exp(-dt / TAU_FLOW))
        if self.compressor:
            self.run_seconds += dt
            target = self.setpoint + 0.05 * self.heat_kw  # a loaded chiller runs a little warm
        else:
            target = self.ambient + 2.0 * self.heat_kw  # no cooling: the water warms with the laser's heat
        self.supply += (target - self.supply) * (1 - math.exp(-dt / TAU_SUPPLY))
        if self.supply > self.setpoint + self.band / 10.0:
            self._above_for += dt
            if self._above_for >= HIGH_TEMP_DELAY:
                self.high_temperature = True  # latched until reset
        else:
            self._above_for = 0.0
        self.low_flow = self.pump_on and self.flow < LOW_FLOW and self._time > 3 * TAU_FLOW
        self.render()

    def render(self) -> None:
        put = self._put
        put("SupplyTemperature", self.supply)
        put("ReturnTemperature", self.return_temperature)
        put("Flow", round(self.flow * 10))
        status = (
            int(self.pump_on and self.flow > 1.0)
            | int(self.compressor) << 1
            | int(self.high_temperature) << 2
            | int(self.low_flow) << 3
        )
        put("StatusWord", status)
        put("RunSeconds", int(self.run_seconds))
        put("Model", MODEL_NAME)
        put("HeatLoad", self.heat_kw)
        put("Setpoint", self.setpoint)
        put("HighTemperatureBand", self.band)
        put("PumpOn", self.pump_on)
        put("AlarmReset", False)
        put("Alarm", self.high_temperature or self.low_flow)

    def value(self, name: str) -> object:
        """A point's value as the registers hold it (for tests and the demo's banner)."""
        f = _FIELDS[name]
        return decode(f, self.image.get(f.table, f.start, f.count))

    def _put(self, name: str, value: object) -> None:
        f = _FIELDS[name]
        self.image.set(f.table, f.start, encode(f, value))

    def _written(self, table: Table, address: int, values: Sequence[int]) -> None:
        """A client's write: checked and applied to the model (the next render shows it)."""
        function = 5 if table is Table.COIL else 16
        if table is Table.COIL:
            for offset, value in enumerate(values):
                if address + offset == 0:
                    self.pump_on = bool(value)
                elif value and self.supply <= self.setpoint + self.band / 10.0:
                    self.high_temperature = False
                    self._above_for = 0.0
            return
        registers = self.image.get(Table.HOLDING, 0, 4)
        registers[address : address + len(values)] = values
        setpoint, band = self.setpoint, self.band
        if address <= 1 and address + len(values) > 0:
            if address != 0 or len(values) < 2:
                raise Refused(
                    function,
                    ExceptionCode.ILLEGAL_DATA_ADDRESS,
                    "the setpoint is written whole (2 registers)",
                )
            setpoint = float(decode(_FIELDS["Setpoint"], registers))
            low, high = SETPOINT_RANGE
            if not low <= setpoint <= high:
                raise Refused(
                    function, ExceptionCode.ILLEGAL_DATA_VALUE, f"setpoint {setpoint} outside 10-30"
                )
        if address + len(values) > 2:
            band = int(decode(_FIELDS["HighTemperatureBand"], registers, 2))
            if not 5 <= band <= 100:
                raise Refused(function, ExceptionCode.ILLEGAL_DATA_VALUE, f"band {band} outside 5-100")
        self.setpoint, self.band = setpoint, band
