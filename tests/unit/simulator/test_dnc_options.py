"""`cnc-simulator`'s DNC options: the DESIGN's ports by default, `off`, the environment, bad settings."""

from __future__ import annotations

import pytest

from simulator import cli
from simulator.dnc import DeviceServer, DncFace, Mode
from simulator.dnc import options as dnc_options
from simulator.machine import Machine
from simulator.store import MemoryStore


def parse(*argv: str) -> object:
    return dnc_options.dnc_options(cli.build_parser().parse_args(list(argv)))


def test_default_ports_are_4001_and_4002_outside_the_tests(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(dnc_options.ENV_TCP, raising=False)
    monkeypatch.delenv(dnc_options.ENV_RFC2217, raising=False)
    options = parse()
    assert options is not None
    assert (options.tcp_port, options.rfc2217_port, options.pty) == (4001, 4002, False)  # type: ignore[attr-defined]
    line = options.spec.line  # type: ignore[attr-defined]
    assert (line.baud, line.format, options.spec.mode) == (9600, "7E2", Mode.LOAD)  # type: ignore[attr-defined]


def test_the_test_suite_turns_them_off_and_off_means_no_face() -> None:
    assert parse() is None  # tests/conftest.py sets both variables to "off"
    only_pty = parse("--dnc-pty")
    assert only_pty is not None and only_pty.tcp_port is None and only_pty.pty  # type: ignore[attr-defined]


def test_explicit_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(dnc_options.ENV_TCP, "5001")
    options = parse("--dnc-rfc2217-port", "0", "--dnc-baud", "4800", "--dnc-format", "7N1",
                    "--dnc-mode", "drip", "--dnc-buffer", "512", "--dnc-handshake", "none")  # fmt: skip
    assert options is not None
    assert (options.tcp_port, options.rfc2217_port) == (5001, 0)  # type: ignore[attr-defined]
    spec = options.spec  # type: ignore[attr-defined]
    assert (spec.line.baud, spec.line.format, spec.line.handshake, spec.mode, spec.buffer_size) == (
        4800, "7N1", "none", Mode.DRIP, 512,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["--dnc-port", "4001", "--dnc-format", "9X9"], "not like 7E2"),
        (["--dnc-port", "4001", "--dnc-baud", "0"], "baud 0"),
        (["--dnc-port", "4001", "--dnc-buffer", "4"], "buffer_size"),
    ],
)
def test_bad_settings_are_refused_in_one_line(argv: list[str], fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        parse(*argv)


def test_a_port_that_is_not_a_number_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["--dnc-port", "modem"])
    assert "not a port number" in capsys.readouterr().err


def test_the_raw_tcp_port_is_a_7bit_device_server_unless_told_otherwise() -> None:
    options = parse("--dnc-port", "0")
    assert options is not None and options.device_server is DeviceServer.SEVEN_BIT  # type: ignore[attr-defined]
    assert options.override is None  # type: ignore[attr-defined]
    options = parse("--dnc-port", "0", "--dnc-device-server", "transparent", "--dnc-override", "800")
    assert options is not None and options.device_server is DeviceServer.TRANSPARENT  # type: ignore[attr-defined]
    assert options.override == 800  # type: ignore[attr-defined]


@pytest.mark.parametrize("override", ["0", "1001", "-5"])
def test_an_override_outside_1_to_1000_is_refused(override: str) -> None:
    with pytest.raises(ValueError, match=f"feed override {override} % is outside 1..1000"):
        parse("--dnc-port", "0", "--dnc-override", override)


def test_an_unknown_device_server_kind_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["--dnc-device-server", "8bit"])
    assert "invalid choice: '8bit'" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("kind", "words"), [("7bit", "no software_parity"), ("transparent", "software_parity: true")]
)
def test_the_banner_says_the_kind_and_the_override(kind: str, words: str) -> None:
    options = parse("--dnc-port", "0", "--dnc-device-server", kind, "--dnc-override", "150")
    assert options is not None
    machine = Machine(MemoryStore())
    face = DncFace(options.spec, machine, MemoryStore(), tcp_port=0, device_server=options.device_server,  # type: ignore[attr-defined]
                   override=options.override)  # type: ignore[attr-defined]  # fmt: skip
    text = "\n".join(dnc_options.dnc_banner(face))
    assert words in text and "feed override 150 %" in text and machine.override == 150
