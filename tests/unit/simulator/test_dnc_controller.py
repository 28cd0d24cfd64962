"""The simulator's DNC controller model in explicit time: flow control, alarms, load, drip, UART garbage."""

from __future__ import annotations

import dataclasses

import pytest

from gateway.codecs.dnc import DC1, DC3, LineSettings, ProgramReceived, ProgramReceiver, frame_program
from simulator.alarms import DNC_BUFFER_OVERFLOW, DNC_COMMUNICATION, DNC_LINE_DROPPED
from simulator.dnc import Coupling, DncController, DncSpec, Frame, Mode, Stage, resample
from simulator.machine import Machine, MachineState
from simulator.store import MemoryStore

LINE = LineSettings(baud=9600)  # 7E2: 872.7 characters per second
SOFT = dataclasses.replace(LINE, software_parity=True)  # what an honest sender uses on a transparent port
PROGRAM = b"%\nO4711 (PART)\nG21 G90\nG0 X10 Y10\nG1 X20 F600\nM30\n%\n"
LONG = b"%\nO4711 (PART)\n" + b"".join(b"G1 X%d F600\n" % i for i in range(20)) + b"M30\n%\n"  # 263 bytes


def controller(mode: Mode = Mode.LOAD, **spec: object) -> tuple[DncController, Machine, MemoryStore]:
    store = MemoryStore({"demo.nc": "%\nO12 (DEMO)\nG0 X1\nM30\n%\n"})
    machine = Machine(store)
    c = DncController(DncSpec(line=LINE, mode=mode, **spec), machine, store)  # type: ignore[arg-type]
    assert c.connect(Coupling(LINE, "transparent"), "test", 0.0)
    return c, machine, store


def wire(program: bytes = PROGRAM) -> bytes:
    return SOFT.encode(frame_program(program, SOFT).data)


def run_line(
    c: DncController, until: float, step: float = 0.001, machine: Machine | None = None, start: float = 0.0
) -> bytes:
    """Advance the model from `start` in small steps (the machine too, if given); what the controller sent."""
    out = bytearray()
    t = start
    while t < until:
        t += step
        if machine is not None:
            machine.step(step)
        c.advance(t)
        out += c.take_output()
    return bytes(out)


def test_connect_arms_a_read_with_dc1_and_a_second_link_is_refused() -> None:
    c, _, _ = controller()
    assert c.stage is Stage.READING
    assert c.take_output() == bytes([DC1])
    assert not c.connect(Coupling(LINE, "transparent"), "other", 0.0)


def test_load_stores_the_program_under_its_o_number_at_line_speed() -> None:
    c, _, store = controller()
    c.take_output()
    data = wire()
    c.feed(data, 0.0)
    c.advance(len(data) / 2 / LINE.bytes_per_second)
    assert c.stats.programs_loaded == 0 and c.stage is Stage.RECEIVING  # half way: the line is not that fast
    run_line(c, len(data) / LINE.bytes_per_second + 0.01)
    assert store.read("O4711") == "%\nO4711 (PART)\nG21 G90\nG0 X10 Y10\nG1 X20 F600\nM30\n%\n"
    assert c.stats.programs_loaded == 1 and c.stats.last_loaded == "O4711" and c.stage is Stage.READING
    assert c.stats.dc3_sent == 0  # the memory keeps up


def test_slow_program_memory_holds_the_sender_with_dc3_and_releases_it_with_dc1() -> None:
    c, _, store = controller(load_rate=100.0, buffer_size=64, high_water=48, low_water=16)
    c.take_output()
    data = wire(LONG)
    c.feed(data, 0.0)
    out = run_line(c, 0.2)
    assert SOFT.decode(out) == (bytes([DC3]), 0)  # 48 characters in, the sender must stop
    # This sender did not stop: everything it sent was already on its way, and counted.
    assert c.stats.after_dc3_last > 0
    assert c.stats.overflows == 1  # 64 bytes of buffer and a slow memory cannot take 263 bytes at once
    assert c.machine.alarms[-1].id == DNC_BUFFER_OVERFLOW
    assert not store.exists("O4711")


def test_flow_control_with_an_obedient_sender() -> None:
    c, _, store = controller(load_rate=200.0, buffer_size=64, high_water=48, low_water=16)
    c.take_output()
    data = wire(LONG)
    sent = 0
    paused = False
    t = 0.0
    events = bytearray()
    while sent < len(data) and t < 5:
        t += 0.001
        if not paused and len(c.wire) < 2:  # an honest sender: two characters ahead of the line
            c.feed(data[sent : sent + 1], t)
            sent += 1
        c.advance(t)
        for char in SOFT.decode(c.take_output())[0]:
            events.append(char)
            paused = char == DC3
    events += SOFT.decode(run_line(c, t + 1, start=t))[0]
    assert DC3 in events and events.count(DC1) >= 1
    assert c.stats.after_dc3_max <= 2
    assert store.exists("O4711")


def test_parity_errors_raise_alarm_085() -> None:
    c, machine, _ = controller()
    c.take_output()
    plain = frame_program(PROGRAM, LINE).data  # no parity bit: a sender set to 8N1
    c.feed(plain, 0.0)
    run_line(c, 0.3)
    assert machine.alarms[-1].id == DNC_COMMUNICATION
    assert c.stats.parity_errors > 0 and c.stage is Stage.ALARM
    machine.reset()
    c.advance(1.0)
    assert c.stage is Stage.READING  # Reset makes the line ready again
    assert c.take_output() == bytes([DC1])


def test_line_drop_during_a_load_raises_086_after_the_device_server_drained() -> None:
    c, machine, _ = controller()
    c.take_output()
    data = wire()
    c.feed(data[:40], 0.0)
    c.disconnect(0.0)
    assert c.connected  # the device server still sends what it holds
    run_line(c, 0.1)
    assert not c.connected
    assert machine.alarms[-1].id == DNC_LINE_DROPPED and c.stats.line_drops == 1


def test_a_complete_load_then_a_closed_connection_is_no_alarm() -> None:
    c, machine, store = controller()
    c.take_output()
    c.feed(wire(), 0.0)
    c.disconnect(0.0)
    run_line(c, 0.2)
    assert store.exists("O4711") and not machine.alarms and c.stage is Stage.OFFLINE


def test_a_slow_memory_takes_a_whole_program_from_its_buffer_after_the_line_closed() -> None:
    c, machine, store = controller(load_rate=100.0)  # 54 bytes take half a second to store
    c.take_output()
    c.feed(wire(), 0.0)
    c.disconnect(0.0)
    run_line(c, 0.1)  # the line carried it all into the 256-byte buffer, then closed
    assert not c.connected and not store.exists("O4711")
    run_line(c, 1.0, start=0.1)
    assert store.exists("O4711") and not machine.alarms and c.stats.line_drops == 0
    assert c.stage is Stage.OFFLINE and c.buffer_level == 0


def test_drip_runs_blocks_as_they_arrive_and_counts_starvation() -> None:
    program = b"%\nO7\nG21 G90\n" + b"".join(b"G1 X%d F60000\n" % (i + 1) for i in range(30)) + b"M30\n%\n"
    c, machine, _ = controller(Mode.DRIP, buffer_size=64, high_water=48, low_water=16)
    c.take_output()
    data = wire(program)
    c.feed(data[:120], 0.0)
    run_line(c, 0.3, machine=machine)
    assert c.stats.drips == 1 and machine.program.name == "DNC O0007"
    # Each 1 mm block runs in 1 ms at 60 m/min: the machine ran dry waiting for the rest.
    assert machine.starvations >= 1 and machine.waiting_for_data
    c.feed(data[120:], 0.3)
    run_line(c, 1.0, machine=machine, start=0.3)
    assert machine.state is MachineState.IDLE and machine.program.part_count == 1
    assert machine.axes[0].actual == pytest.approx(30.0)
    assert c.stage is Stage.READING  # ready for the next one


def test_punch_sends_leader_markers_and_blocks_at_line_speed() -> None:
    c, _, _ = controller()
    c.take_output()
    c.punch("demo.nc")
    assert c.stage is Stage.PUNCHING
    out = run_line(c, 0.2)
    chars, errors = SOFT.decode(out)
    assert errors == 0
    received = [e for e in ProgramReceiver().feed(chars) if isinstance(e, ProgramReceived)]
    assert received == [ProgramReceived(b"O12 (DEMO)\nG0 X1\nM30\n", 12, "DEMO", b"")]
    assert chars.endswith(bytes([DC1]))  # and then it reads again
    with pytest.raises(Exception, match="not in the program store"):
        c.punch("missing.nc")


def test_remote_request_is_a_punched_program_naming_what_is_wanted() -> None:
    c, _, _ = controller()
    c.take_output()
    c.request("O4711")
    chars, _ = SOFT.decode(run_line(c, 0.2))
    received = [e for e in ProgramReceiver().feed(chars) if isinstance(e, ProgramReceived)]
    assert received[0].text == b"O9999 (PRG=O4711)\nM30\n"
    assert c.stage is Stage.READING
    with pytest.raises(Exception, match="leaves the folder"):
        c.request("../x")


# --- the UART --------------------------------------------------------------------------------------


def test_same_settings_pass_unchanged() -> None:
    frame = Frame(9600, 7, "E", 2)
    assert resample(b"G0 X1\n", frame, frame) == (b"G0 X1\n", 0)


def test_a_7e2_receiver_reads_8n1_characters_with_parity_errors() -> None:
    text = b"G01 X10 Y20\n"
    chars, errors = resample(text, Frame(9600, 8, "N", 1), Frame(9600, 7, "E", 2))
    assert chars == text  # same rate: the 7 data bits arrive, bit 7 lands on the parity bit
    assert errors == sum(1 for c in text if c.bit_count() % 2)  # every character with odd weight


def test_a_wrong_baud_rate_gives_garbage_and_framing_errors() -> None:
    text = b"%\nO4711\nG0 X10 Y10\nM30\n%" * 3
    chars, errors = resample(text, Frame(19200, 7, "E", 2), Frame(9600, 7, "E", 2))
    assert chars != text and errors > 0
    slow, slow_errors = resample(text, Frame(4800, 7, "E", 2), Frame(9600, 7, "E", 2))
    assert slow != text and slow_errors > 0


def test_couplings_emulate_parity_on_transparent_links_and_resample_on_rfc2217() -> None:
    raw = Coupling(LINE, "transparent")
    assert raw.to_controller(SOFT.encode(b"G0\n")) == (b"G0\n", 0)
    assert raw.to_sender(bytes([DC3])) == (bytes([0x93]), 0)  # DC3 with its even parity bit
    peer = Frame(9600, 8, "N", 1)
    rfc = Coupling(LINE, "rfc2217", lambda: peer)
    chars, errors = rfc.to_controller(b"G1\n")
    assert chars == b"G1\n" and errors == 1  # same rate: the data arrives; "1" (0x31) has odd weight
    assert Coupling(LINE, "rfc2217", lambda: Frame.of(LINE)).to_controller(b"G1\n") == (b"G1\n", 0)


def test_a_7bit_device_server_hands_dc1_and_dc3_on_as_0x11_and_0x13() -> None:
    seven = Coupling(LINE, "7bit")
    assert seven.to_sender(bytes([DC1, DC3])) == (b"\x11\x13", 0)  # its UART took the parity bit off


def test_a_7bit_device_server_sends_the_low_7_bits_whatever_bit_7_was() -> None:
    seven = Coupling(LINE, "7bit")
    text = b"G01 X10 Y20\n"
    assert seven.to_controller(SOFT.encode(text)) == (text, 0)  # software parity: bit 7 dropped, no error
    assert seven.to_controller(text) == (text, 0)  # plain 7-bit characters: the UART adds the parity bit
    assert seven.to_controller(bytes(c | 0x80 for c in text)) == (text, 0)  # bit 7 set everywhere


def test_a_transparent_port_without_software_parity_gives_the_controller_parity_errors() -> None:
    raw = Coupling(LINE, "transparent")
    text = b"G01 X10 Y20\n"
    chars, errors = raw.to_controller(text)
    assert chars == text and errors == sum(1 for c in text if c.bit_count() % 2)  # odd weight: bit 7 wrong
    assert raw.to_sender(bytes([DC3])) == (b"\x93", 0)  # and its DC3 comes with the parity bit as bit 7


def test_a_7bit_device_server_set_to_another_parity_hands_on_what_it_read_and_counts_the_errors() -> None:
    odd = Frame(9600, 7, "O", 2)  # the device server's port set 7O2, the controller's line 7E2
    seven = Coupling(LINE, "7bit", uart=odd)
    out, errors = seven.to_sender(bytes([DC1, DC3, ord("%")]))
    assert out == b"\x11\x13%"  # the 7 data bits all the same, bit 7 = 0
    assert errors == 3  # every character had the "wrong" parity bit for 7O2
    chars, bad = seven.to_controller(b"G1\n")
    assert chars == b"G1\n" and bad == 3  # and the controller sees the odd parity bits as errors


def test_a_7bit_device_server_counts_what_it_passes_on_with_an_error() -> None:
    c, _, _ = controller()
    c.disconnect(0.0)
    c.advance(0.0)
    assert c.connect(Coupling(LINE, "7bit", uart=Frame(9600, 7, "O", 2)), "test", 0.1)
    assert c.take_output() == b"\x11"  # the DC1 of the new read
    assert c.stats.device_errors == 1


def test_unknown_link_kinds_and_a_uart_on_another_kind_are_refused() -> None:
    with pytest.raises(ValueError, match="unknown link kind 'tcp'"):
        Coupling(LINE, "tcp")
    with pytest.raises(ValueError, match="uart"):
        Coupling(LINE, "transparent", uart=Frame(9600, 7, "O", 2))
