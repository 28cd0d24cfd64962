"""The simulated laser cutter: a pure, time-stepped model of axes, laser, program and alarms.

Nothing here knows about asyncio, sockets or wall-clock time. `step(dt)` advances
simulated time by `dt` seconds, so tests run a whole program deterministically
in milliseconds and the runner decides how fast simulated time flows. Commands
(`start`, `select_program`, `set_override`, ...) act at once and raise a
`RequestError` (gateway.errors) whose `status` is what the controller answers when it
refuses them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum

from gateway.errors import InvalidArgument, InvalidState, OutOfRange
from simulator.alarms import Alarm, program_not_found
from simulator.errors import ProgramNotFound
from simulator.interpreter import (
    SOFT_LIMITS,
    Action,
    BeginBlock,
    Dwell,
    Fault,
    Move,
    ProgramEnd,
    ProgramStop,
    SetLaser,
    SetPower,
    plan_program,
)
from simulator.store import ProgramStore, check_name

RAPID = 30000.0  # mm/min, G0 and the cap for any feed
AMBIENT = 25.0  # degC
GAS_ON = 12.0  # bar while the beam is on
POWER_TABLE = (20.0, 40.0, 60.0, 80.0, 100.0)  # % of S over five feed bands
OVERRIDE_MAX = 200  # % the panel's knob (and the OPC UA variable) goes to
#: % a machine may be set to cut at from the command line (cnc-simulator --dnc-override): beyond the knob,
#: it stands for everything that makes a machine cut faster than its program's F words say (rapids faster
#: than an estimator assumes, feed per revolution read as mm/min, macros): 8x and more. The rapid still caps
#: every feed: a program's F times the override must stay below `rapid` to run that much faster.
OVERRIDE_LIMIT = 1000

# Time constants (s) of the first-order lags.
TAU_POWER = 0.05
TAU_GAS_UP = 0.3
TAU_GAS_DOWN = 1.0
TAU_HEAD = 40.0
HEAD_RISE_AT_MAX = 35.0  # degC above ambient at full power, in steady state


class MachineState(IntEnum):
    IDLE = 0
    RUNNING = 1
    PAUSED = 2
    ALARM = 3

    @property
    def text(self) -> str:
        return self.name.capitalize()


class Mode(IntEnum):
    AUTO = 0
    MANUAL = 1
    MDA = 2

    @property
    def text(self) -> str:
        return {Mode.AUTO: "Auto", Mode.MANUAL: "Manual", Mode.MDA: "MDA"}[self]


@dataclass(slots=True)
class Axis:
    name: str
    actual: float = 0.0
    commanded: float = 0.0
    velocity: float = 0.0  # mm/min, signed
    referenced: bool = True  # homed at power-on, for simplicity


@dataclass(slots=True)
class Laser:
    on: bool = False
    power_set: float = 0.0  # W, the programmed S
    power_act: float = 0.0  # W
    gas_pressure: float = 0.0  # bar
    head_temp: float = AMBIENT  # degC
    power_table: tuple[float, ...] = POWER_TABLE


@dataclass(slots=True)
class ProgramStatus:
    name: str = ""
    block: int = 0  # line number of the block being executed
    block_text: str = ""
    progress: float = 0.0  # %
    part_count: int = 0
    run_time: float = 0.0  # s of simulated time while running


#: Gives the actions of the next block of a streamed (drip-fed) program, or None while none has arrived.
Refill = Callable[[], "list[Action] | None"]


@dataclass(slots=True)
class _Run:
    """Where execution stands in a planned program (or in a streamed one, planned as it arrives)."""

    actions: list[Action]
    total_path: float  # mm of the moves planned so far
    refill: Refill | None = None
    waiting: bool = False  # a streamed program ran out of blocks and waits for more
    index: int = 0
    along: float = 0.0  # mm along the current move, or s into the current dwell
    done_path: float = 0.0  # mm of completed moves
    beam_before_pause: bool = False


@dataclass(slots=True)
class Machine:
    store: ProgramStore
    limits: dict[str, tuple[float, float]] = field(default_factory=lambda: dict(SOFT_LIMITS))
    rapid: float = RAPID
    ambient: float = AMBIENT
    block_delete: bool = True  # the block-delete switch: '/' blocks are skipped

    axes: tuple[Axis, Axis, Axis] = field(default_factory=lambda: (Axis("X"), Axis("Y"), Axis("Z")))
    laser: Laser = field(default_factory=Laser)
    feed_rate: float = 0.0  # mm/min, actual path feed
    override: int = 100  # %
    state: MachineState = MachineState.IDLE
    mode: Mode = Mode.AUTO
    program: ProgramStatus = field(default_factory=ProgramStatus)
    alarms: list[Alarm] = field(default_factory=list)
    ignore_start: bool = False  # test hook: Start is accepted and ignored
    emergency_stop: bool = False  # the e-stop button is pressed (no motion; the tests press it)
    sim_time: float = 0.0
    starvations: int = 0  # times a drip-fed program ran out of blocks while running
    _run: _Run | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self.laser.head_temp = self.ambient

    # --- commands ------------------------------------------------------------------------------

    def select_program(self, name: str) -> None:
        if self.state in (MachineState.RUNNING, MachineState.PAUSED):
            raise InvalidState(f"cannot select a program while {self.state.text.lower()}")
        try:
            check_name(name)
        except ValueError as exc:
            raise InvalidArgument(str(exc)) from None
        if not self.store.exists(name):
            raise InvalidArgument(f"program {name!r} is not in the program store")
        self.program.name = name

    def start(self) -> None:
        if self.ignore_start:
            return
        if self.state is MachineState.PAUSED:
            self.resume()
            return
        if self.state is MachineState.ALARM:
            raise InvalidState("cannot start with active alarms: reset first")
        if self.state is not MachineState.IDLE:
            raise InvalidState("a program is already running")
        name = self.program.name
        if not name:
            raise InvalidState("no program selected")
        try:
            text = self.store.read(name)
        except ProgramNotFound:
            self.raise_alarm(program_not_found(name))
            raise InvalidState(f"program {name!r} is no longer in the program store") from None
        start = (self.axes[0].actual, self.axes[1].actual, self.axes[2].actual)
        plan = plan_program(text, start, limits=self.limits, block_delete=self.block_delete)
        self._run = _Run(list(plan.actions), plan.total_path)
        self.program.progress = 0.0
        self.program.run_time = 0.0
        self.state = MachineState.RUNNING

    def start_stream(self, name: str, refill: Refill) -> None:
        """Run a program whose blocks arrive while it runs (DNC drip feed): `refill` gives the next
        block's actions (planned with `interpreter.StreamPlanner`), or None while none has arrived;
        the machine then holds, and counts a starvation, until one does."""
        if self.state is MachineState.ALARM:
            raise InvalidState("cannot start with active alarms: reset first")
        if self.state is not MachineState.IDLE:
            raise InvalidState("a program is already running")
        self.program.name = name
        self._run = _Run([], 0.0, refill)
        self.program.progress = 0.0
        self.program.run_time = 0.0
        self.state = MachineState.RUNNING

    @property
    def waiting_for_data(self) -> bool:
        """A drip-fed program is running and its next block has not arrived."""
        return self._run is not None and self._run.waiting

    def stop(self) -> None:
        """Abort the program (accepted, and harmless, when nothing runs)."""
        if self.state in (MachineState.RUNNING, MachineState.PAUSED):
            self._finish()

    def pause(self) -> None:
        """Feed hold: motion stops at once and the beam goes off until Resume."""
        if self.state is MachineState.PAUSED:
            return
        if self.state is not MachineState.RUNNING or self._run is None:
            raise InvalidState("nothing is running")
        self._run.beam_before_pause = self.laser.on
        self.laser.on = False
        self.state = MachineState.PAUSED
        self._halt()

    def resume(self) -> None:
        if self.state is MachineState.RUNNING:
            return
        if self.state is not MachineState.PAUSED or self._run is None:
            raise InvalidState("nothing is paused")
        self.laser.on = self._run.beam_before_pause
        self.state = MachineState.RUNNING

    def reset(self) -> None:
        """Abort whatever runs, clear every alarm, return to Idle."""
        self._finish()
        self.alarms.clear()
        self.state = MachineState.IDLE

    def set_override(self, percent: int, *, limit: int = OVERRIDE_MAX) -> None:
        """The feed override; `limit` OVERRIDE_LIMIT for the command line's setting beyond the knob."""
        if not 0 <= percent <= limit:
            raise OutOfRange(f"feed override {percent} % is outside 0..{limit} %")
        self.override = percent

    def set_mode(self, mode: int) -> None:
        try:
            self.mode = Mode(mode)
        except ValueError:
            raise OutOfRange(f"mode {mode} is not one of 0 Auto, 1 Manual, 2 MDA") from None

    def raise_alarm(self, alarm: Alarm) -> None:
        if alarm not in self.alarms:
            self.alarms.append(alarm)
        if alarm.stops_machine:
            self._finish()
            self.state = MachineState.ALARM

    # --- time --------------------------------------------------------------------------------

    def step(self, dt: float) -> None:
        """Advance simulated time by `dt` seconds: run the program, then the laser's lags."""
        if dt < 0 or not math.isfinite(dt):
            raise ValueError(f"dt must be a finite number >= 0, got {dt!r}")
        left = dt
        while self.state is MachineState.RUNNING and self._run is not None:
            run = self._run
            if run.index >= len(run.actions):
                if not self._refill(run):
                    break  # a drip-fed program waits for its next block; time still passes
                continue
            action = run.actions[run.index]
            if isinstance(action, Move):
                feed = self._feed_of(action)
                remaining = action.segment.length - run.along
                if feed <= 0:
                    self._moving(action, feed)
                    break  # override 0: the path holds, time still passes
                needed = remaining / (feed / 60.0)
                if needed > left:
                    self._elapse(left)
                    run.along += left * feed / 60.0
                    left = 0.0
                    self._moving(action, feed)
                    break
                self._elapse(needed)
                left -= needed
                run.done_path += action.segment.length
                self._place(action.segment.end)
                self._next()
            elif isinstance(action, Dwell):
                self._halt()
                needed = action.seconds - run.along
                if needed > left:
                    self._elapse(left)
                    run.along += left
                    left = 0.0
                    break
                self._elapse(needed)
                left -= needed
                self._next()
            else:
                self._instant(action)
        self._elapse(left)
        self._update_progress()

    # --- internals -----------------------------------------------------------------------------

    def _refill(self, run: _Run) -> bool:
        more = run.refill() if run.refill is not None else None
        if not more:
            if not run.waiting:
                run.waiting = True
                self.starvations += 1
                self._halt()
            return False
        run.waiting = False
        run.actions.extend(more)
        run.total_path += sum(a.segment.length for a in more if isinstance(a, Move))
        return True

    def _feed_of(self, move: Move) -> float:
        if move.feed is None:
            return self.rapid
        return min(move.feed * self.override / 100.0, self.rapid)

    def _instant(self, action: Action) -> None:
        assert self._run is not None
        if isinstance(action, BeginBlock):
            self.program.block = action.line
            self.program.block_text = action.text
            self._set_commanded()
            self._next()
        elif isinstance(action, SetPower):
            self.laser.power_set = action.watts
            self._next()
        elif isinstance(action, SetLaser):
            self.laser.on = action.on
            self._next()
        elif isinstance(action, ProgramStop):
            self._next()
            self.pause()
        elif isinstance(action, ProgramEnd):
            if action.count_part:
                self.program.part_count += 1
            self.program.progress = 100.0
            self._finish()
        elif isinstance(action, Fault):
            self.raise_alarm(action.alarm)
        else:  # pragma: no cover - every action type is handled above
            raise TypeError(f"unknown action {action!r}")

    def _next(self) -> None:
        assert self._run is not None
        self._run.index += 1
        self._run.along = 0.0

    def _set_commanded(self) -> None:
        """Commanded position: the end point of the current block's motion, if it has one."""
        assert self._run is not None
        actions = self._run.actions
        for action in actions[self._run.index + 1 :]:
            if isinstance(action, Move):
                for axis, value in zip(self.axes, action.segment.end, strict=True):
                    axis.commanded = value
                return
            if isinstance(action, (BeginBlock, ProgramEnd, Fault)):
                break
        for axis in self.axes:
            axis.commanded = axis.actual

    def _moving(self, move: Move, feed: float) -> None:
        assert self._run is not None
        self._place(move.segment.at(self._run.along))
        tangent = move.segment.tangent(self._run.along)
        for axis, t in zip(self.axes, tangent, strict=True):
            axis.velocity = feed * t
        self.feed_rate = feed

    def _place(self, point: tuple[float, float, float]) -> None:
        for axis, value in zip(self.axes, point, strict=True):
            axis.actual = value
        self._halt()

    def _halt(self) -> None:
        for axis in self.axes:
            axis.velocity = 0.0
        self.feed_rate = 0.0

    def _finish(self) -> None:
        """End of a run, for whatever reason: beam off, axes still, back to Idle."""
        self._run = None
        self._halt()
        for axis in self.axes:
            axis.commanded = axis.actual
        self.laser.on = False
        self.laser.power_set = 0.0
        if self.state is not MachineState.ALARM:
            self.state = MachineState.IDLE

    def _update_progress(self) -> None:
        run = self._run
        if run is None or self.state is MachineState.ALARM:
            return
        total = run.total_path
        if total <= 0:
            return
        done = run.done_path
        if run.index < len(run.actions) and isinstance(run.actions[run.index], Move):
            done += run.along
        self.program.progress = min(100.0, 100.0 * done / total)

    def _elapse(self, t: float) -> None:
        """Let `t` seconds pass with the machine as it is now: run time and the laser's lags."""
        if t <= 0:
            return
        self.sim_time += t
        if self.state is MachineState.RUNNING:
            self.program.run_time += t
        laser = self.laser
        target = laser.power_set if laser.on else 0.0
        laser.power_act = _lag(laser.power_act, target, TAU_POWER, t) if laser.on else 0.0
        gas_target = GAS_ON if laser.on else 0.0
        tau = TAU_GAS_UP if laser.on else TAU_GAS_DOWN
        laser.gas_pressure = _lag(laser.gas_pressure, gas_target, tau, t)
        heat = self.ambient + HEAD_RISE_AT_MAX * laser.power_act / 6000.0
        laser.head_temp = _lag(laser.head_temp, heat, TAU_HEAD, t, snap=0.01)


def _lag(value: float, target: float, tau: float, t: float, snap: float = 1e-3) -> float:
    """First-order lag over `t` seconds, snapping to the target once close (no endless tiny changes)."""
    value = target + (value - target) * math.exp(-t / tau)
    return target if abs(value - target) < snap else value
