"""Passwords cnc-gateway publishes (its examples, the demo, docker-compose.yml) are refused at start-up, by
file, line and key (issue 23, item 4): users' and inbox accounts' hashes, and the inbox's passwords from the
environment. `cnc-gateway hash-password` will not hash them either."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gateway.auth.known_passwords import KNOWN_PASSWORDS, is_known, known_passwords_of
from gateway.auth.passwords import hash_password
from gateway.config.loader import load
from gateway.errors import ConfigError, ConfigIssue

ROOT = Path(__file__).resolve().parents[3]
BIN = Path(sys.executable).parent
# The hash mappings/gateway.example.yaml shipped for `operator` and `nesting` before issue 23: "change-me".
SHIPPED = "scrypt$16384$8$1$twhDt2RIBmI4Q0VV/AFVKg==$GGx0VeNkLGN90LL1vrK4tHEvA6FubkrzuxdA4E25vUM="
MAPPING = """\
machine: m1
driver: {endpoint: 'opc.tcp://127.0.0.1:4841'}
variables:
  - {path: A, source: 'ns=2;s=A', type: Double}
"""


def cheap(password: str) -> str:
    return hash_password(password, n=2**10)


def write(tmp_path: Path, text: str) -> Path:
    (tmp_path / "m1.yaml").write_text(MAPPING, encoding="utf-8")
    path = tmp_path / "gateway.yaml"
    path.write_text("machines: [m1.yaml]\n" + text, encoding="utf-8")
    return path


def issues(path: Path, environ: dict[str, str] | None = None) -> list[ConfigIssue]:
    with pytest.raises(ConfigError) as info:
        load([path], environ=environ or {})
    return info.value.issues


def test_the_hash_the_example_shipped_is_refused_naming_file_line_and_key(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "users:\n"
        f"  - {{name: olga, role: operator, password_hash: '{cheap('olga-2024-winter')}'}}\n"
        f"  - {{name: operator, role: operator, password_hash: '{SHIPPED}'}}\n",
    )
    [issue] = issues(path)
    assert (issue.file, issue.line, issue.key) == (str(path), 4, "users[1].password_hash")
    assert issue.message.startswith("this is the hash of 'change-me', a password published in cnc-gateway's")
    assert "cnc-gateway hash-password" in issue.message


def test_every_published_password_is_refused_in_every_place_a_login_takes_one(tmp_path: Path) -> None:
    users = "".join(
        f"  - {{name: u{i}, role: viewer, password_hash: '{cheap(p)}'}}\n"
        for i, p in enumerate(KNOWN_PASSWORDS)
    )
    path = write(
        tmp_path,
        f"users:\n{users}"
        "inbox:\n"
        "  accounts:\n"
        f"    - {{user: nest, password_hash: '{cheap('nesting')}'}}\n"
        "    - {user: office, password_env: OFFICE_PW}\n"
        "    - {user: night, password_env: NIGHT_PW}\n",
    )
    found = {
        (i.line, i.key): i.message for i in issues(path, {"OFFICE_PW": "change-me", "NIGHT_PW": "n1ght!"})
    }
    n = len(KNOWN_PASSWORDS)
    for i, password in enumerate(KNOWN_PASSWORDS):
        assert found[(3 + i, f"users[{i}].password_hash")].startswith(f"this is the hash of {password!r}")
    assert found[(5 + n, "inbox.accounts[0].password_hash")].startswith("this is the hash of 'nesting'")
    assert found[(6 + n, "inbox.accounts[1].password_env")].startswith(
        "environment variable OFFICE_PW holds 'change-me'"
    )
    assert len(found) == n + 2  # the night shift's own password passes


def test_passwords_of_ones_own_load(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        f"users:\n  - {{name: olga, role: operator, password_hash: '{cheap('Operator-7!')}'}}\n"
        "inbox:\n  accounts:\n    - {user: nest, password_env: NEST_PW}\n",
    )
    config = load([path], environ={"NEST_PW": "change-me-not"})
    assert [u.name for u in config.gateway.users] == ["olga"]


def test_known_passwords_of_checks_each_hash_once() -> None:
    own, known = cheap("a-real-one"), cheap("admin")
    assert known_passwords_of([own, known, own]) == {known: "admin"}
    assert is_known("change-me") and not is_known("change-me-2")


def test_the_shipped_example_gateway_file_carries_no_hash_and_runs_with_the_environment() -> None:
    example = ROOT / "mappings" / "gateway.example.yaml"
    assert "scrypt$" not in example.read_text(encoding="utf-8").replace("scrypt$16384$8$1$…", "")
    env = {"CNC_OPERATOR_PASSWORD_HASH": cheap("olga-2024-winter"), "CNC_INBOX_PASSWORD": "n3st-2024"}
    assert [u.name for u in load([example], environ=env).gateway.users] == ["operator"]
    with pytest.raises(ConfigError, match="CNC_OPERATOR_PASSWORD_HASH is not set"):
        load([example], environ={})
    [issue] = issues(example, {**env, "CNC_OPERATOR_PASSWORD_HASH": SHIPPED})
    assert issue.key == "users[0].password_hash" and "'change-me'" in issue.message
    [issue] = issues(example, {**env, "CNC_INBOX_PASSWORD": "change-me"})
    assert issue.key == "inbox.accounts[0].password_env"


@pytest.mark.parametrize("password", ["change-me", "operator"])
def test_hash_password_will_not_hash_a_published_password(password: str) -> None:
    proc = subprocess.run(
        [str(BIN / "cnc-gateway"), "hash-password", "--stdin"],
        input=f"{password}\n", capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 1 and proc.stdout == ""
    assert f"error: {password!r} is published in cnc-gateway's docs and examples" in proc.stderr
