"""Serial DNC (RS-232, directly or through a serial device server): a pure, sans-I/O codec.

Nothing here opens a port or waits; transports (the gateway's delivery, the
simulator's controller) own the I/O and feed these state machines.

    settings = LineSettings.from_format("7E2", LineSettings(baud=9600))
    wire = frame_program(program_bytes, settings)        # leader, %, blocks, %; index offset -> line
    sender = DncSender(wire, settings)                    # waits for the controller's DC1
    sender.feed(port.read())                              # [Resume()], [Pause()], [Junk(...)]
    port.write(chunk := sender.next_chunk()); sender.sent(len(chunk))

    receiver = ProgramReceiver()                          # PUNCH: [ProgramStarted, ProgramReceived(...)]
    parse_request(received.text)                          # O9999 (PRG=O4711) -> RemoteRequest("O4711")
    restart_lines(program_bytes, 120)                     # header + modal block + line 120 onwards
    DripScheduler(lead_time=30).next_grant(now)           # earliest-dry-first drip feeding
"""

from gateway.codecs.dnc.framing import (
    GENERATED,
    FramingError,
    ProgramLines,
    SourceLine,
    WireProgram,
    frame_program,
    split_program,
)
from gateway.codecs.dnc.line import (
    CONTROL_BYTES,
    DC1,
    DC2,
    DC3,
    DC4,
    EndOfBlock,
    Handshake,
    LineSettings,
    LineSettingsError,
    Parity,
)
from gateway.codecs.dnc.receiver import (
    Overflow,
    ProgramReceived,
    ProgramReceiver,
    ProgramStarted,
    ReceiverEvent,
    Unterminated,
)
from gateway.codecs.dnc.request import (
    BadRequest,
    RemoteRequest,
    answer_program,
    check_name,
    not_found,
    parse_request,
)
from gateway.codecs.dnc.restart import restart_lines
from gateway.codecs.dnc.runtime import block_times
from gateway.codecs.dnc.schedule import BlockCost, DripLine, DripScheduler, Grant, program_costs
from gateway.codecs.dnc.sender import DncSender, Junk, Pause, Resume, SenderEvent

__all__ = [
    "CONTROL_BYTES",
    "DC1",
    "DC2",
    "DC3",
    "DC4",
    "GENERATED",
    "BadRequest",
    "BlockCost",
    "DncSender",
    "DripLine",
    "DripScheduler",
    "EndOfBlock",
    "FramingError",
    "Grant",
    "Handshake",
    "Junk",
    "LineSettings",
    "LineSettingsError",
    "Overflow",
    "Parity",
    "Pause",
    "ProgramLines",
    "ProgramReceived",
    "ProgramReceiver",
    "ProgramStarted",
    "ReceiverEvent",
    "RemoteRequest",
    "Resume",
    "SenderEvent",
    "SourceLine",
    "Unterminated",
    "WireProgram",
    "answer_program",
    "block_times",
    "check_name",
    "frame_program",
    "not_found",
    "parse_request",
    "program_costs",
    "restart_lines",
    "split_program",
]
