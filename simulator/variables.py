"""The PLC's variables: B&R-style node ids, data types, and how each reads (and writes) the machine.

This table is the single source of the simulator's interface; the OPC UA server
builds its address space from it and mappings/laser-sim.yaml names the same ids.
Node ids follow B&R's scheme: `::AsGlobalPV:<global>.<member>` for global
variables and `::<task>:<local>` for task-local ones.

The table is plain data, so more variables can be appended without touching the
server: the benchmark noise mode (simulator/noise.py) appends its variables,
marked `pushed`, and writes them itself at a set rate.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from simulator.machine import Machine

NAMESPACE_URI = "urn:cnc-simulator:plc"

Getter = Callable[[Machine], Any]
Setter = Callable[[Machine, Any], None]


@dataclass(frozen=True, slots=True)
class Variable:
    """One PLC variable. `type` is an OPC UA built-in type name, `[]` for an array."""

    node_id: str  # the string identifier in namespace 2, e.g. "::AsGlobalPV:gAxis[0].ActPos"
    type: str
    read: Getter
    write: Setter | None = None  # None: read-only
    description: str = ""
    array_length: int = 0  # 0: variable length (for arrays)
    pushed: bool = False  # written by a driver of its own (noise mode), not read at every tick

    @property
    def writable(self) -> bool:
        return self.write is not None

    @property
    def name(self) -> str:
        """Browse name: the last member, e.g. `ActPos`."""
        return _split(self.node_id)[1].split(".")[-1]

    @property
    def ancestors(self) -> tuple[tuple[str, str], ...]:
        """(node id, browse name) of each folder and object above the variable, below Objects/PLC.

        `::AsGlobalPV:gAxis[0].ActPos` sits in Global/gAxis/gAxis[0]; `::Laser:headTemp`
        in Tasks/Laser. Arrays of structures are objects holding one object per element,
        so a browsing client finds arrays, structures and members as a B&R PLC shows them.
        """
        scope, name = _split(self.node_id)
        prefix = f"::{scope}:"
        found: list[tuple[str, str]] = (
            [(GLOBAL_FOLDER, "Global")]
            if scope == "AsGlobalPV"
            else [
                (TASKS_FOLDER, "Tasks"),
                (f"::{scope}", scope),
            ]
        )
        path = ""
        for part in name.split(".")[:-1]:
            array = re.fullmatch(r"(.+)\[\d+\]", part)
            if array:
                found.append((prefix + path + array.group(1), array.group(1)))
            found.append((prefix + path + part, part))
            path += part + "."
        return tuple(found)


PLC_FOLDER = "PLC"
GLOBAL_FOLDER = "PLC.Global"
TASKS_FOLDER = "PLC.Tasks"


def _split(node_id: str) -> tuple[str, str]:
    match = re.fullmatch(r"::([^:]+):(.+)", node_id)
    if match is None:
        raise ValueError(f"not a B&R-style node id: {node_id!r}")
    return match.group(1), match.group(2)


def _command(action: Callable[[Machine], None]) -> Setter:
    """PLC-style trigger: writing true runs the command, writing false does nothing."""

    def write(machine: Machine, value: Any) -> None:
        if value:
            action(machine)

    return write


def _set_ignore_start(machine: Machine, value: Any) -> None:
    machine.ignore_start = bool(value)


def _axis(index: int) -> list[Variable]:
    base = f"::AsGlobalPV:gAxis[{index}]"
    name = "XYZ"[index]
    return [
        Variable(
            f"{base}.ActPos",
            "Double",
            lambda m: m.axes[index].actual,
            description=f"Actual {name} position, mm",
        ),
        Variable(
            f"{base}.CmdPos", "Double", lambda m: m.axes[index].commanded, description=f"Commanded {name}, mm"
        ),
        Variable(
            f"{base}.Velocity",
            "Double",
            lambda m: m.axes[index].velocity,
            description=f"{name} velocity, mm/min",
        ),
        Variable(
            f"{base}.Referenced",
            "Boolean",
            lambda m: m.axes[index].referenced,
            description=f"{name} is homed",
        ),
    ]


def build_variables() -> list[Variable]:
    """The laser cutter's variables, in browse order."""
    g = "::AsGlobalPV:"
    return [
        *_axis(0),
        *_axis(1),
        *_axis(2),
        Variable(g + "gLaser.On", "Boolean", lambda m: m.laser.on, description="Beam on"),
        Variable(
            g + "gLaser.PowerSet", "Double", lambda m: m.laser.power_set, description="Programmed power S, W"
        ),
        Variable(
            g + "gLaser.PowerAct", "Double", lambda m: m.laser.power_act, description="Measured power, W"
        ),
        Variable(
            g + "gLaser.GasPressure", "Double", lambda m: m.laser.gas_pressure, description="Assist gas, bar"
        ),
        Variable(
            "::Laser:headTemp",
            "Float",
            lambda m: m.laser.head_temp,
            description="Cutting head temperature, degC",
        ),
        Variable(
            "::Laser:powerTable",
            "Double[]",
            lambda m: list(m.laser.power_table),
            description="Power ramp over feed, %",
            array_length=5,
        ),
        Variable(g + "gFeed.Act", "Double", lambda m: m.feed_rate, description="Actual path feed, mm/min"),
        Variable(
            g + "gFeed.Override",
            "UInt16",
            lambda m: m.override,
            lambda m, v: m.set_override(v),
            description="Feed override 0..200 %",
        ),
        Variable(
            g + "gMachine.State",
            "Int16",
            lambda m: int(m.state),
            description="0 Idle, 1 Running, 2 Paused, 3 Alarm",
        ),
        Variable(g + "gMachine.StateText", "String", lambda m: m.state.text),
        Variable(
            g + "gMachine.Mode",
            "Int16",
            lambda m: int(m.mode),
            lambda m, v: m.set_mode(v),
            description="0 Auto, 1 Manual, 2 MDA",
        ),
        Variable(g + "gMachine.ModeText", "String", lambda m: m.mode.text),
        Variable(
            g + "gMachine.EmergencyStop",
            "Boolean",
            lambda m: m.emergency_stop,
            description="The emergency stop button is pressed",
        ),
        Variable(g + "gProgram.Name", "String", lambda m: m.program.name, description="Selected program"),
        Variable(
            g + "gProgram.Block", "UInt32", lambda m: m.program.block, description="Line of the current block"
        ),
        Variable(g + "gProgram.BlockText", "String", lambda m: m.program.block_text),
        Variable(g + "gProgram.Progress", "Double", lambda m: m.program.progress, description="Path done, %"),
        Variable(
            g + "gProgram.PartCount",
            "UInt32",
            lambda m: m.program.part_count,
            description="M2/M30 since power-on",
        ),
        Variable(
            g + "gProgram.RunTime",
            "Double",
            lambda m: m.program.run_time,
            description="Run time of the program, s",
        ),
        Variable(g + "gAlarms.Count", "UInt16", lambda m: len(m.alarms)),
        Variable(g + "gAlarms.Ids", "UInt32[]", lambda m: [a.id for a in m.alarms]),
        Variable(g + "gAlarms.Texts", "String[]", lambda m: [a.text for a in m.alarms]),
        Variable(g + "gAlarms.Severities", "UInt16[]", lambda m: [int(a.severity) for a in m.alarms]),
        Variable(
            g + "gCmd.Start",
            "Boolean",
            lambda m: False,
            _command(Machine.start),
            description="Write true: start",
        ),
        Variable(
            g + "gCmd.Stop",
            "Boolean",
            lambda m: False,
            _command(Machine.stop),
            description="Write true: abort",
        ),
        Variable(
            g + "gCmd.Pause",
            "Boolean",
            lambda m: False,
            _command(Machine.pause),
            description="Write true: feed hold",
        ),
        Variable(
            g + "gCmd.Resume",
            "Boolean",
            lambda m: False,
            _command(Machine.resume),
            description="Write true: resume",
        ),
        Variable(
            g + "gCmd.Reset",
            "Boolean",
            lambda m: False,
            _command(Machine.reset),
            description="Write true: reset",
        ),
        Variable(
            g + "gCmd.SelectProgram",
            "String",
            lambda m: m.program.name,
            lambda m, v: m.select_program(v),
            description="Write a program name to select it",
        ),
        Variable(
            g + "gSim.IgnoreStart",
            "Boolean",
            lambda m: m.ignore_start,
            _set_ignore_start,
            description="Test hook: accept Start and do nothing",
        ),
    ]
