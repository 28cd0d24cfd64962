"""`cnc-gateway check` with access control on: each writable variable's write role, each command's role
and allowed states, and each COPYDATA target with the ids it sends."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

from gateway.auth.passwords import hash_password
from gateway.cli.check import id_ranges, print_config
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config
from gateway.config.mapping import MachineMapping

MAPPING: dict[str, Any] = {
    "machine": "m1",
    "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
    "defaults": {"write_role": "engineer"},
    "variables": [
        {"path": "State", "source": "s", "type": "Int16", "copydata": {"id": 3}},
        {
            "path": "Override",
            "source": "o",
            "type": "UInt16",
            "access": "readwrite",
            "role": "operator",
            "copydata": {"id": 1},
        },
        {"path": "Mode", "source": "m", "type": "Int16", "access": "readwrite", "copydata": {"id": 2}},
        {"path": "Stop", "source": "st", "type": "Boolean", "access": "readwrite"},
        {"path": "Power", "source": "p", "type": "Double", "copydata": {"id": 7}},
    ],
    "commands": {
        "stop": {
            "writes": [{"path": "Stop", "value": True}],
            "role": "admin",
            "allowed": {"path": "State", "not": [0, 3], "names": {0: "Idle", 1: "Running", 3: "Alarm"}},
        },
        "hold": {"writes": [{"path": "Stop", "value": True}], "allowed": {"path": "State", "not": 2}},
    },
    "copydata": {
        "targets": [
            {
                "name": "nest",
                "transport": "tcp-client",
                "host": "10.0.0.5",
                "port": 5020,
                "accept_writes": True,
            },
            {
                "name": "dash",
                "transport": "udp",
                "host": "10.0.0.6",
                "port": 5021,
                "variables": ["Power", "Override"],
            },
        ]
    },
}


def check_output(gateway: dict[str, Any]) -> list[str]:
    config = Config(
        GatewayConfig.model_validate(gateway), (MachineMapping.model_validate(MAPPING),), Path.cwd()
    )
    out = io.StringIO()
    print_config(config, out)
    return out.getvalue().splitlines()


def line(lines: list[str], start: str) -> list[str]:
    return next(x for x in lines if x.strip().startswith(start)).split()


def test_with_users_each_writable_variable_shows_its_write_role() -> None:
    users = [{"name": "olga", "role": "operator", "password_hash": hash_password("secret", n=2**10)}]
    lines = check_output({"users": users, "access": {"copydata_role": "operator"}})
    assert line(lines, "Override")[1:] == ["UInt16", "-", "readwrite", "role", "operator,", "copydata", "1"]
    assert line(lines, "Mode")[4:6] == ["role", "engineer,"]  # the machine's defaults.write_role
    assert line(lines, "State")[1:] == ["Int16", "-", "read", "copydata", "3"]  # read-only: no role
    assert line(lines, "stop") == ["stop", "admin", "State", "is", "none", "of", "Idle,", "Alarm"]
    assert line(lines, "hold") == ["hold", "operator", "State", "is", "not", "2"]  # no names: the value
    nest = " ".join(line(lines, "nest"))
    assert (
        nest == "nest tcp-client 10.0.0.5:5020 batch ids 1-3, 7 (4 variables) accepts writes (role operator)"
    )
    dash = " ".join(line(lines, "dash"))
    assert dash == "dash udp 10.0.0.6:5021 batch ids 1, 7 (2 variables)"
    assert lines[-1] == "access control on: 1 user(s), roles viewer < operator < engineer < admin"


def test_without_users_no_write_roles_are_shown_and_the_summary_says_so() -> None:
    lines = check_output({})
    assert line(lines, "Override")[1:] == ["UInt16", "-", "readwrite", "copydata", "1"]
    assert line(lines, "stop")[1] == "admin"  # a command's own role is part of its definition
    # COPYDATA writes never get an implied role (the loader refuses such a mapping; `check` on a Config built
    # otherwise says they are refused).
    assert " ".join(line(lines, "nest")).endswith("accepts writes (role none: refused)")
    assert lines[-1] == (
        "no users: OPC UA clients are anonymous, with role viewer (access.anonymous); "
        "writes and commands the mappings open to MQTT act as admin; COPYDATA writes as nobody: refused "
        "(access.copydata_role)"
    )
    named = check_output({"access": {"copydata_role": "operator"}})
    assert " ".join(line(named, "nest")).endswith("accepts writes (role operator)")
    assert named[-1].endswith("COPYDATA writes as operator (access.copydata_role)")


def test_with_access_off_the_summary_says_anonymous_clients_may_change_the_machines() -> None:
    lines = check_output({"access": {"enabled": False}})
    assert lines[-1] == (
        "access control off (access.enabled: false): no role is checked; "
        "anonymous OPC UA clients may change what the mappings allow"
    )


def test_id_ranges_join_runs() -> None:
    assert id_ranges([1, 2, 3, 5, 7, 8]) == "1-3, 5, 7-8"
    assert id_ranges([4]) == "4" and id_ranges([]) == "none"
