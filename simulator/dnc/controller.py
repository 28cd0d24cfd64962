"""The controller's end of a serial DNC line: a Fanuc-style reader/punch interface (pure, explicit time).

Nothing here does I/O or reads a clock: the face (face.py) hands in what came
from the link with the time (`feed`), calls `advance(now)` and writes out what
`take_output()` gives. Time is real seconds; the line runs at its baud rate
times the simulator's speed factor.

Receiving: bytes from the sender wait in the device server's buffer (`wire`,
bounded by `device_buffer`: beyond it the link is not read, so TCP pushes
back) and reach the controller one character time apart. The controller keeps
them in its receive buffer (`buffer_size`): it sends DC3 when the buffer
reaches `high_water` and DC1 when it is back at `low_water`; characters that
arrive after its DC3 are counted (the sender's honesty), and one beyond the
buffer raises alarm 087. A parity or framing error raises 085, a line that drops
during a transfer 086 (Fanuc's numbers).

Modes:
- load: the program between `%` markers goes into the program store (the one
  the FTP face serves), named after its O-number (`O4711`); `load_rate` slows
  the store down (chars/s of simulated time) so that flow control shows;
- drip: blocks run as they arrive: once the buffer holds `high_water` bytes
  (or the whole program), the machine starts and pulls one block at a time;
  when it finds the buffer empty it waits and counts a starvation.

Punching: the controller sends a stored program (leader, `%`, blocks, `%`)
paced at the line rate, held while the receiving side sends DC3; a remote
request is a punched `O9999 (PRG=<name>)` program, after which the controller
reads the answer in its current mode.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

from gateway.codecs.dnc import (
    DC1,
    DC3,
    FramingError,
    LineSettings,
    Overflow,
    ProgramReceived,
    ProgramReceiver,
    ProgramStarted,
    check_name,
    frame_program,
)
from gateway.codecs.dnc.receiver import ReceiverEvent
from gateway.codecs.dnc.sender import Junk
from gateway.errors import InvalidArgument, InvalidState
from simulator.alarms import (
    DNC_BUFFER_OVERFLOW,
    DNC_COMMUNICATION,
    DNC_LINE_DROPPED,
    NO_PROGRAM_SPACE,
    Alarm,
    dnc_buffer_overflow,
    dnc_communication,
    dnc_line_dropped,
    no_program_space,
)
from simulator.dnc.uart import Coupling
from simulator.errors import ProgramNotFound
from simulator.interpreter import Action, ProgramEnd, StreamPlanner
from simulator.machine import Machine, MachineState

DNC_ALARMS = frozenset({NO_PROGRAM_SPACE, DNC_COMMUNICATION, DNC_LINE_DROPPED, DNC_BUFFER_OVERFLOW})
#: Per-episode counts of characters after DC3 kept for statistics (p99 and the like).
EPISODES_KEPT = 10_000
#: Drip-fed lines kept in `executed` (tests compare them with the program, byte for byte).
EXECUTED_KEPT = 200_000
DC1_REPEAT = 0.5  # s (real time) between DC1s while a read waits for its first character
_FEED = bytes([0x00, 0x7F])  # NUL and DEL: leader and tape feed, never buffered
_O_NUMBER = re.compile(rb"^\s*O\s*0*(\d{1,8})", re.IGNORECASE)


class Mode(StrEnum):
    LOAD = "load"
    DRIP = "drip"


class Stage(StrEnum):
    OFFLINE = "offline"  # no link
    IDLE = "idle"  # linked, not reading (no DC1 sent)
    READING = "reading"  # DC1 sent, waiting for a program
    RECEIVING = "receiving"  # load: between the markers
    BUFFERING = "buffering"  # drip: filling the buffer before the machine starts
    RUNNING = "running"  # drip: the machine runs the blocks as they come
    PUNCHING = "punching"
    ALARM = "alarm"  # a DNC alarm stopped the line until Reset


class WritableStore(Protocol):
    def read(self, name: str) -> str: ...

    def write(self, name: str, data: bytes) -> None: ...


@dataclass(frozen=True, slots=True)
class DncSpec:
    """How the simulated controller's serial DNC face is set up."""

    line: LineSettings = field(default_factory=LineSettings)  # 9600 7E2, XON/XOFF, LF, 20 NULs, % markers
    mode: Mode = Mode.LOAD
    buffer_size: int = 256
    high_water: int | None = None  # DC3 level; default buffer_size - 32 (room for a sluggish sender)
    low_water: int | None = None  # DC1 level; default buffer_size // 4
    device_buffer: int = 1024  # bytes the device server holds before TCP pushes back
    load_rate: float | None = None  # chars/s the program memory takes in load mode; None: at once
    max_program: int = 4 * 1024 * 1024  # program memory (alarm 070 beyond)
    request_number: int = 9999
    request_key: str = "PRG"
    auto_dc1: bool = True  # send DC1 as soon as a link comes (the operator pressed READ / cycle start)

    def __post_init__(self) -> None:
        if self.buffer_size < 8:
            raise ValueError("buffer_size must be >= 8 bytes")
        if not 0 <= self.low <= self.high <= self.buffer_size:
            raise ValueError("need 0 <= low_water <= high_water <= buffer_size")
        if self.device_buffer < 1 or self.max_program < 1:
            raise ValueError("device_buffer and max_program must be >= 1")
        if self.load_rate is not None and self.load_rate <= 0:
            raise ValueError("load_rate must be > 0")

    @property
    def high(self) -> int:
        return self.high_water if self.high_water is not None else max(1, self.buffer_size - 32)

    @property
    def low(self) -> int:
        return self.low_water if self.low_water is not None else self.buffer_size // 4


@dataclass(slots=True)
class DncStats:
    rx_chars: int = 0  # characters that reached the controller
    tx_chars: int = 0
    ignored: int = 0  # characters that came while the controller was not reading
    dc3_sent: int = 0
    dc1_sent: int = 0
    after_dc3_last: int = 0
    after_dc3_max: int = 0
    after_dc3_total: int = 0
    parity_errors: int = 0
    device_errors: int = 0  # our characters a 7-bit device server's UART received with an error, handed on
    junk: int = 0
    overflows: int = 0
    line_drops: int = 0
    programs_loaded: int = 0
    last_loaded: str = ""
    drips: int = 0
    punches: int = 0
    requests: int = 0
    request_reply: str = ""


class DncController:
    """One serial port of the controller; one link at a time."""

    def __init__(
        self,
        spec: DncSpec,
        machine: Machine,
        store: WritableStore,
        *,
        speed: float = 1.0,
        on_change: Callable[[], None] | None = None,
    ) -> None:
        if speed <= 0:
            raise ValueError("speed must be > 0")
        self.spec = spec
        self.line = spec.line
        self.machine = machine
        self.store = store
        self.mode = spec.mode
        self.rate = spec.line.bytes_per_second * speed  # characters per real second
        self.on_change = on_change or (lambda: None)
        self.stats = DncStats()
        self.episodes: deque[int] = deque(maxlen=EPISODES_KEPT)
        #: Every line a drip feed handed to the interpreter, in order, as it came (without its line end).
        self.executed: deque[bytes] = deque(maxlen=EXECUTED_KEPT)
        self.stage = Stage.OFFLINE
        self.link: str = ""
        self._coupling: Coupling | None = None
        self.wire = bytearray()
        self._rx_free_at = 0.0
        self.rx = bytearray()
        self._xoff = False
        self._after_dc3 = 0
        self._flow_out = bytearray()
        self._data_out = bytearray()
        self._tx_free_at = 0.0
        self._tx_held = False  # the other side sent DC3 while we punch
        self._after_punch: str | None = None  # "request" when a remote request is being punched
        self._receiver = ProgramReceiver(max_size=spec.max_program)
        self._load_credit = 0.0
        self._load_last: float | None = None
        self._skip_to_percent = False
        self._planner: StreamPlanner | None = None
        self._drip_end = False  # the drip program's closing % is in the buffer
        self._drip_seen_start = False
        self._closing = False  # the link is gone; the device server still drains `wire`
        self._got_data = False  # something arrived since the last DC1 that armed a read
        self._last_dc1: float | None = None

    # --- the link ------------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._coupling is not None

    def connect(self, coupling: Coupling, name: str, now: float) -> bool:
        """A link came up; False if another one holds the port (the device server refuses it)."""
        if self._coupling is not None:
            return False
        self._closing = False
        self._coupling = coupling
        self.link = name
        self.wire.clear()
        self._rx_free_at = self._tx_free_at = now
        self._tx_held = False
        self.stage = Stage.ALARM if self._dnc_alarm_active() else Stage.IDLE
        if self.stage is Stage.IDLE and self.spec.auto_dc1:
            self._arm()
        self.on_change()
        return True

    def disconnect(self, now: float) -> None:
        """The link went down. What the device server (or the pty) still holds reaches the line first,
        as on a real one; then the line drops, with alarm 086 if a transfer was under way."""
        if self._coupling is None or self._closing:
            return
        self._closing = True
        self._flow_out.clear()
        self._data_out.clear()
        self._after_punch = None
        if not self.wire:
            self._drop()

    def _drop(self) -> None:
        during = {
            Stage.RECEIVING: "a program load",
            Stage.BUFFERING: "a drip feed",
            Stage.RUNNING: "a drip feed",
            Stage.PUNCHING: "a punch",
        }.get(self.stage)
        drip_complete = self.stage is Stage.RUNNING and (
            self._drip_end or self.machine.state not in (MachineState.RUNNING, MachineState.PAUSED)
        )
        self._coupling = None
        self._closing = False
        self.link = ""
        self.wire.clear()
        if drip_complete or self._load_buffered():
            # The whole program arrived: the machine runs what it holds, or the program memory takes the
            # rest of the buffer (a slow one, `load_rate`); the line is simply gone.
            self.on_change()
            return
        if during is not None:
            self.stats.line_drops += 1
            self._alarm(dnc_line_dropped(during))
        self._reset_reading()
        self.stage = Stage.OFFLINE
        self.on_change()

    def wire_room(self) -> int:
        """How many more bytes the device server takes from the link now."""
        return self.spec.device_buffer - len(self.wire)

    def feed(self, data: bytes, now: float) -> None:
        """Bytes from the link (the sender's port), into the device server's buffer."""
        if not data or self._coupling is None or self._closing:
            return
        if not self.wire:
            self._rx_free_at = max(self._rx_free_at, now)
        self.wire += data

    def take_output(self) -> bytes:
        """Bytes for the link now (flow control first, then paced data), as the sender's port reads them."""
        if not self._flow_out or self._coupling is None or self._closing:
            self._flow_out.clear()
            return b""
        chars = bytes(self._flow_out)
        self._flow_out.clear()
        out, errors = self._coupling.to_sender(chars)
        self.stats.device_errors += errors
        return out

    # --- commands ------------------------------------------------------------------------------

    def set_mode(self, mode: str) -> None:
        try:
            new = Mode(mode)
        except ValueError:
            raise InvalidArgument(f"DNC mode {mode!r} is not one of load, drip") from None
        if self.stage in (Stage.RECEIVING, Stage.BUFFERING, Stage.RUNNING, Stage.PUNCHING):
            raise InvalidState(f"cannot change the DNC mode while {self.stage.value}")
        self.mode = new

    def arm(self) -> None:
        """The operator starts a read (EDIT + READ, or cycle start in RMT): DC1 goes out."""
        if self._coupling is None:
            raise InvalidState("no DNC link is connected")
        if self.stage is Stage.ALARM:
            raise InvalidState("DNC alarm active: reset first")
        if self.stage not in (Stage.IDLE, Stage.READING):
            raise InvalidState(f"the DNC line is busy ({self.stage.value})")
        self._arm()
        self.on_change()

    def punch(self, name: str) -> None:
        """Send a stored program to the link (PUNCH), with leader and % markers."""
        self._check_can_send()
        try:
            text = self.store.read(name)
        except ProgramNotFound:
            raise InvalidArgument(f"program {name!r} is not in the program store") from None
        try:
            wire = frame_program(text.encode("utf-8"), self.line)
        except FramingError as exc:
            raise InvalidArgument(f"program {name!r} cannot be punched: {exc}") from None
        self._start_punch(wire.data, "punch")
        self.stats.punches += 1

    def request(self, name: str) -> None:
        """Punch a remote request for `name` (`O9999 (PRG=<name>)`), then read the answer."""
        reason = check_name(name)
        if reason is not None:
            raise InvalidArgument(f"cannot request {name!r}: {reason.lower()}")
        self._check_can_send()
        key = self.spec.request_key
        text = f"%\nO{self.spec.request_number:04d} ({key}={name})\nM30\n%\n".encode("ascii")
        self._start_punch(frame_program(text, self.line).data, "request")
        self.stats.requests += 1
        self.stats.request_reply = ""

    def _check_can_send(self) -> None:
        if self._coupling is None:
            raise InvalidState("no DNC link is connected")
        if self.stage is Stage.ALARM:
            raise InvalidState("DNC alarm active: reset first")
        if self.stage not in (Stage.IDLE, Stage.READING):
            raise InvalidState(f"the DNC line is busy ({self.stage.value})")

    def _start_punch(self, data: bytes, what: str) -> None:
        self._reset_reading()
        self._data_out = bytearray(data)
        self._after_punch = what
        self.stage = Stage.PUNCHING
        self.on_change()

    # --- time ----------------------------------------------------------------------------------

    def advance(self, now: float) -> None:
        """Let the line run until `now`: deliver what is due, store or run it, flow control, punch."""
        self._check_reset()
        self._receive_due(now)
        self._drain_load(now)
        self._drip_progress()
        self._flow_check()
        self._transmit_due(now)
        self._repeat_dc1(now)
        if self._closing and not self.wire:
            self._drop()

    def _repeat_dc1(self, now: float) -> None:
        """DC1 again while reading and nothing came: a DC1 sent before the sender listened is lost
        (pyserial empties its input when it opens a port), and senders wait for it."""
        if self.stage is not Stage.READING or self._got_data or self._coupling is None or self._closing:
            return
        if self._last_dc1 is None:
            self._last_dc1 = now
        elif now - self._last_dc1 >= DC1_REPEAT:
            self._send_flow(DC1)
            self._last_dc1 = now

    def next_due(self, now: float) -> float | None:
        """When `advance` next has something to do on its own (a character due), None if nothing."""
        times: list[float] = []
        if self.wire:
            step = 1.0 / self.rate
            count = 1
            if self.stage in _READING_STAGES:
                # Wake exactly when the character that reaches the DC3 level (or overflows) is due.
                limit = self.spec.buffer_size + 1 if self._xoff else self.spec.high
                count = max(1, limit - len(self.rx))
            times.append(self._rx_free_at + min(count, len(self.wire)) * step)
        if self._data_out and not self._tx_held:
            times.append(self._tx_free_at + 1.0 / self.rate)
        if self.mode is Mode.LOAD and self.spec.load_rate is not None and self.rx:
            times.append(now + 1.0 / self.spec.load_rate)
        return min(times) if times else None

    # --- receiving -----------------------------------------------------------------------------

    def _receive_due(self, now: float) -> None:
        if not self.wire or self._coupling is None:
            return
        due = int((now - self._rx_free_at) * self.rate + 1e-9)
        count = min(due, len(self.wire))
        if count <= 0:
            return
        if not self._xoff and self.stage in _READING_STAGES:
            count = min(count, max(1, self.spec.high - len(self.rx)))  # stop at the DC3 level
        data = bytes(self.wire[:count])
        del self.wire[:count]
        self._rx_free_at += count / self.rate
        chars, errors = self._coupling.to_controller(data)
        self.stats.rx_chars += len(chars)
        self._flow_from_sender(chars)
        chars = chars.translate(None, bytes([DC1, 0x12, DC3, 0x14]))
        if errors:
            self.stats.parity_errors += errors
            if self.stage in _READING_STAGES:
                self._alarm(dnc_communication(errors, "parity/framing error(s)"))
                return
        if self.stage not in _READING_STAGES:
            self.stats.ignored += len(chars)
            return
        chars = chars.translate(None, _FEED)
        if self._skip_to_percent:
            pct = chars.find(b"%")
            if pct < 0:
                return
            chars = chars[pct + 1 :]
            self._skip_to_percent = False
        if chars:
            self._buffer(chars)

    def _flow_from_sender(self, chars: bytes) -> None:
        """DC3/DC1 from the other side hold and release what we punch."""
        for char in chars:
            if char == DC3:
                self._tx_held = True
            elif char == DC1:
                self._tx_held = False

    def _buffer(self, chars: bytes) -> None:
        self._got_data = True
        level = len(self.rx)
        n = len(chars)
        if self._xoff:
            self._count_after_dc3(n)
        elif level + n >= self.spec.high:
            self._send_flow(DC3)
            self._xoff = True
            self._after_dc3 = 0
            self._count_after_dc3(level + n - self.spec.high)
        self.rx += chars
        if len(self.rx) > self.spec.buffer_size:
            self.stats.overflows += 1
            self._alarm(dnc_buffer_overflow(self.spec.buffer_size, self._after_dc3))

    def _count_after_dc3(self, n: int) -> None:
        if n <= 0:
            return
        self._after_dc3 += n
        self.stats.after_dc3_total += n
        self.stats.after_dc3_last = self._after_dc3
        self.stats.after_dc3_max = max(self.stats.after_dc3_max, self._after_dc3)

    def _flow_check(self) -> None:
        if self._xoff and len(self.rx) <= self.spec.low and self.stage in _READING_STAGES:
            self._release()

    def _release(self) -> None:
        self.episodes.append(self._after_dc3)
        self._xoff = False
        self._after_dc3 = 0
        self._send_flow(DC1)

    def _send_flow(self, char: int) -> None:
        self._flow_out.append(char)
        if char == DC3:
            self.stats.dc3_sent += 1
        else:
            self.stats.dc1_sent += 1
        self.on_change()

    def _arm(self) -> None:
        self.stage = Stage.READING
        self._reset_reading()
        self._send_flow(DC1)

    def _reset_reading(self) -> None:
        self._got_data = False
        self._last_dc1 = None
        if self._xoff:
            self.episodes.append(self._after_dc3)
        self.rx.clear()
        self._xoff = False
        self._after_dc3 = 0
        self._receiver = ProgramReceiver(max_size=self.spec.max_program)
        self._load_credit = 0.0
        self._planner = None
        self._drip_end = False
        self._drip_seen_start = False

    # --- load ----------------------------------------------------------------------------------

    def _drain_load(self, now: float) -> None:
        if self.mode is not Mode.LOAD or self.stage not in (Stage.READING, Stage.RECEIVING) or not self.rx:
            return
        if self.spec.load_rate is None:
            count = len(self.rx)
        else:
            last = now if self._load_last is None else self._load_last
            speed = self.rate / self.line.bytes_per_second
            self._load_credit += max(0.0, now - last) * self.spec.load_rate * speed
            count = min(len(self.rx), int(self._load_credit))
            self._load_credit -= count
        self._load_last = now
        if count <= 0:
            return
        data = bytes(self.rx[:count])
        del self.rx[:count]
        for event in self._receiver.feed(data):
            self._load_event(event)
            if self.alarmed:
                return

    def _load_buffered(self) -> bool:
        """A load's closing `%` is in the receive buffer: the program has reached the controller whole."""
        if self.mode is not Mode.LOAD:
            return False
        markers = self.rx.count(b"%")
        return (self.stage is Stage.RECEIVING and markers >= 1) or (
            self.stage is Stage.READING and markers >= 2
        )

    def _load_event(self, event: ReceiverEvent) -> None:
        if isinstance(event, ProgramStarted):
            self.stage = Stage.RECEIVING
        elif isinstance(event, ProgramReceived):
            self._store(event)
            self.stage = Stage.READING
            if self._coupling is None:  # the line went while the memory took the program's end
                self._reset_reading()
                self.stage = Stage.OFFLINE
        elif isinstance(event, Overflow):
            self._alarm(no_program_space(event.limit))
        elif isinstance(event, Junk):
            self.stats.junk += event.count

    def _store(self, program: ProgramReceived) -> None:
        if program.number == self.spec.request_number:
            comment = program.name or ""
            self.stats.request_reply = comment
        name = self._program_name(program)
        self.store.write(name, b"%\n" + program.text + b"%\n")
        self.stats.programs_loaded += 1
        self.stats.last_loaded = name
        self.on_change()

    @staticmethod
    def _program_name(program: ProgramReceived) -> str:
        if program.number is not None:
            return f"O{program.number:04d}"
        if program.name and check_name(program.name) is None:
            return program.name
        return "DNC.nc"

    # --- drip ----------------------------------------------------------------------------------

    def _drip_progress(self) -> None:
        if self.mode is not Mode.DRIP:
            return
        if self.stage is Stage.READING and not self._drip_seen_start:
            pct = self.rx.find(b"%")
            if pct < 0:
                junk = len(self.rx.translate(None, b"\r\n \t"))
                self.stats.junk += junk
                self.rx.clear()
                return
            self.stats.junk += len(bytes(self.rx[:pct]).translate(None, b"\r\n \t"))
            del self.rx[: pct + 1]
            self._drip_seen_start = True
            self.stage = Stage.BUFFERING
        if self.stage is Stage.BUFFERING and self._drip_seen_start:
            # The rest of the `%` line (a header such as O1234) is read with the first block.
            self._drip_end = self._end_marker_buffered()
            if self._xoff or len(self.rx) >= self.spec.high or self._drip_end:
                self._start_drip()
        elif self.stage is Stage.RUNNING:
            if not self._drip_end:
                self._drip_end = self._end_marker_buffered()
            if self.machine.state not in (MachineState.RUNNING, MachineState.PAUSED):
                self._drip_done()

    def _end_marker_buffered(self) -> bool:
        return b"\n%" in self.rx or self.rx.startswith(b"%")

    def _start_drip(self) -> None:
        machine = self.machine
        if machine.state is not MachineState.IDLE:
            self._alarm(
                dnc_communication(0, f"drip feed refused: the machine is {machine.state.text.lower()}")
            )
            return
        # The first line is the rest of the `%` line: usually empty, else a header such as O1234.
        nl = self.rx.find(b"\n")
        if nl >= 0 and not self.rx[:nl].strip(b" \t\r"):
            del self.rx[: nl + 1]
        match = _O_NUMBER.match(bytes(self.rx.split(b"\n", 1)[0]))
        name = f"DNC O{int(match.group(1)):04d}" if match else "DNC"
        start = (machine.axes[0].actual, machine.axes[1].actual, machine.axes[2].actual)
        self._planner = StreamPlanner(start, limits=machine.limits, block_delete=machine.block_delete)
        machine.start_stream(name, self._pull)
        self.stage = Stage.RUNNING
        self.stats.drips += 1

    def _pull(self) -> list[Action] | None:
        """The machine asks for the next block (Machine.start_stream's refill)."""
        planner = self._planner
        if planner is None:
            return None
        while True:
            nl = self.rx.find(b"\n")
            if nl < 0:
                if self.rx.lstrip(b" \t\r").startswith(b"%"):
                    return self._end_of_stream()
                return None
            raw = bytes(self.rx[:nl]).removesuffix(b"\r")
            del self.rx[: nl + 1]
            self.on_change()  # the buffer drained: perhaps DC1
            if raw.lstrip(b" \t").startswith(b"%"):
                return self._end_of_stream()
            self.executed.append(raw)
            acts, ended = planner.feed(raw.decode("ascii", "replace"))
            if ended:
                self._planner = None
                return acts
            if acts:
                return acts

    def _end_of_stream(self) -> list[Action]:
        self._planner = None
        return [ProgramEnd(count_part=False)]

    def _drip_done(self) -> None:
        """The drip program ended (M30, its closing %, an alarm, Reset): back to reading or idle."""
        self._planner = None
        closing_seen = self._drip_end
        self._reset_reading()
        self._skip_to_percent = not closing_seen
        if self.stage is Stage.ALARM:
            return
        if self.machine.state is MachineState.ALARM:
            self.stage = Stage.ALARM  # a program alarm: Reset makes the line ready again
            return
        if self._coupling is None:
            self.stage = Stage.OFFLINE
        elif self.spec.auto_dc1:
            self._arm()
        else:
            self.stage = Stage.IDLE

    # --- punching ------------------------------------------------------------------------------

    def _transmit_due(self, now: float) -> None:
        if self._coupling is None or self.stage is not Stage.PUNCHING:
            return
        if self._tx_held or not self._data_out:
            self._tx_free_at = max(self._tx_free_at, now)
        else:
            due = int((now - self._tx_free_at) * self.rate + 1e-9)
            count = min(due, len(self._data_out))
            if count > 0:
                self._flow_out += self._data_out[:count]
                del self._data_out[:count]
                self._tx_free_at += count / self.rate
                self.stats.tx_chars += count
        if not self._data_out:
            what, self._after_punch = self._after_punch, None
            self.stage = Stage.IDLE
            if what == "request" or self.spec.auto_dc1:
                self._arm()

    # --- alarms --------------------------------------------------------------------------------

    def _alarm(self, alarm: Alarm) -> None:
        self.machine.raise_alarm(alarm)
        self._reset_reading()
        self._data_out.clear()
        self._skip_to_percent = False
        self.stage = Stage.ALARM
        self.on_change()

    def _dnc_alarm_active(self) -> bool:
        return any(a.id in DNC_ALARMS for a in self.machine.alarms)

    def _check_reset(self) -> None:
        """Reset on the machine clears the DNC alarm: the line is ready again."""
        if (
            self.stage is Stage.ALARM
            and not self._dnc_alarm_active()
            and self.machine.state is not MachineState.ALARM
        ):
            self.stage = Stage.IDLE if self._coupling is not None else Stage.OFFLINE
            if self.stage is Stage.IDLE and self.spec.auto_dc1:
                self._arm()

    # --- reporting -----------------------------------------------------------------------------

    @property
    def alarmed(self) -> bool:
        return self.stage is Stage.ALARM

    @property
    def buffer_level(self) -> int:
        return len(self.rx)

    @property
    def xoff(self) -> bool:
        return self._xoff


_READING_STAGES = frozenset({Stage.READING, Stage.RECEIVING, Stage.BUFFERING, Stage.RUNNING})
