from __future__ import annotations

import pytest

from simulator.cli import build_parser
from simulator.runner import DEFAULT_FTP_PASSWORD, DEFAULT_FTP_USER, Simulator


def test_ftp_credentials_come_from_arguments_then_environment_then_defaults(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("CNC_SIM_FTP_USER", raising=False)
    monkeypatch.delenv("CNC_SIM_FTP_PASSWORD", raising=False)
    plain = Simulator()
    assert (
        (plain.ftp_user, plain.ftp_password)
        == (DEFAULT_FTP_USER, DEFAULT_FTP_PASSWORD)
        == ("cnc", "simulator")
    )
    monkeypatch.setenv("CNC_SIM_FTP_USER", "envuser")
    monkeypatch.setenv("CNC_SIM_FTP_PASSWORD", "envpass")
    env = Simulator()
    assert (env.ftp_user, env.ftp_password) == ("envuser", "envpass")
    given = Simulator(ftp_user="u", ftp_password="p")
    assert (given.ftp_user, given.ftp_password) == ("u", "p")


def test_defaults_match_the_laser_sim_mapping() -> None:
    sim = Simulator()
    assert sim.opcua_endpoint == "opc.tcp://127.0.0.1:4841" and sim.ftp_port == 2122
    args = build_parser().parse_args([])
    assert (args.host, args.opcua_port, args.ftp_port, args.speed, args.loop) == (
        "127.0.0.1",
        4841,
        2122,
        1.0,
        None,
    )


@pytest.mark.parametrize("argv", [["--speed", "0"], ["--speed", "fast"], ["--tick", "-1"]])
def test_cli_rejects_bad_numbers(argv: list[str]) -> None:
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(argv)
    assert info.value.code == 2


def test_simulator_rejects_bad_speed() -> None:
    with pytest.raises(ValueError):
        Simulator(speed=0)
