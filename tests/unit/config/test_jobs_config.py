"""The gateway file's `inbox:` section and the mapping's `jobs:` section: defaults and refusals."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from gateway.auth.passwords import hash_password
from gateway.config.gateway import GatewayConfig
from gateway.config.jobs import InboxConfig, JobsConfig, Retry
from gateway.config.loader import load
from gateway.errors import ConfigError

HASH = hash_password("pw", n=2**10)


def test_inbox_defaults_are_safe() -> None:
    inbox = GatewayConfig().inbox
    assert inbox.port == 2121 and inbox.accounts == [] and inbox.anonymous is False
    assert inbox.max_file_size == 64 * 1024 * 1024 and inbox.tls is None


def test_sizes_take_units() -> None:
    assert InboxConfig(max_file_size="2 MiB").max_file_size == 2 * 1024 * 1024


@pytest.mark.parametrize(
    ("account", "fragment"),
    [
        ({"user": "nest"}, "exactly one of password_hash and password_env"),
        ({"user": "nest", "password_hash": HASH, "password_env": "X"}, "exactly one"),
        ({"user": "nest", "password_hash": "hunter2"}, "scrypt$N$r$p$salt$key"),
        ({"user": "nest", "password_env": "1BAD"}, "not an environment variable name"),
        ({"user": "anonymous", "password_hash": HASH}, "anonymous: true"),
        ({"user": "has space", "password_hash": HASH}, "must be 1-64"),
        ({"user": "nest", "password_hash": HASH, "machines": ["Laser!"]}, "not a machine name"),
    ],
)
def test_bad_accounts_are_refused(account: dict[str, object], fragment: str) -> None:
    with pytest.raises(ValidationError) as info:
        InboxConfig.model_validate({"accounts": [account]})
    assert fragment in str(info.value)


def test_duplicate_accounts_and_bad_ranges_are_refused() -> None:
    with pytest.raises(ValidationError, match="defined twice"):
        InboxConfig.model_validate({"accounts": [{"user": "a", "password_hash": HASH}] * 2})
    with pytest.raises(ValidationError, match="max must not be below min"):
        InboxConfig.model_validate({"passive_ports": {"min": 30010, "max": 30000}})
    with pytest.raises(ValidationError, match=r"look like \.part"):
        InboxConfig.model_validate({"temp_suffixes": ["part"]})


def test_jobs_defaults() -> None:
    jobs = JobsConfig.model_validate({"controller": {"host": "10.0.0.5"}})
    c = jobs.controller
    assert (c.port, c.folder, c.upload, c.tls, c.user) == (
        21,
        "/DATA/Programs",
        "temp-rename",
        "none",
        "anonymous",
    )
    assert jobs.duplicates == "skip" and jobs.max_attempts == 5 and jobs.auto is None
    assert jobs.validation.dialect == "generic"


def test_retry_backoff_grows_and_is_capped() -> None:
    retry = Retry(initial=2, max=10, factor=2)
    assert [retry.delay(n) for n in range(1, 6)] == [2, 4, 8, 10, 10]


def test_an_auto_block_must_do_something() -> None:
    with pytest.raises(ValidationError, match="select, start or both"):
        JobsConfig.model_validate({"controller": {"host": "h"}, "auto": {}})


def test_gateway_file_inbox_errors_are_located(tmp_path: Path) -> None:
    (tmp_path / "m.yaml").write_text(
        "machine: m\ndriver: {endpoint: 'opc.tcp://127.0.0.1:4841'}\nvariables:\n"
        "  - {path: A, source: 'ns=2;s=a', type: Double}\n"
    )
    gw = tmp_path / "gateway.yaml"
    gw.write_text(
        "machines: [m.yaml]\ninbox:\n  port: 2121\n  accounts:\n    - user: nest\n      password_hash: nope\n"
    )
    with pytest.raises(ConfigError) as info:
        load([gw], environ={})
    issue = info.value.issues[0]
    assert issue.line == 6 and issue.key == "inbox.accounts[0].password_hash"


def _serial_machine(folder: Path, name: str, controller: str) -> str:
    (folder / f"{name}.yaml").write_text(
        f"machine: {name}\ndriver: {{endpoint: 'opc.tcp://127.0.0.1:4841'}}\nvariables:\n"
        "  - {path: A, source: 'ns=2;s=a', type: Double}\n"
        f"jobs:\n  controller: {controller}\n"
    )
    return f"{name}.yaml"


def test_lines_sharing_a_link_must_agree_on_its_capacity(tmp_path: Path) -> None:
    serial = "{type: serial, where: 'socket://10.0.0.9:%d', mode: drip, link: nport-7, link_capacity: %d}"
    files = [
        _serial_machine(tmp_path, "fanuc-1", serial % (4001, 4000)),
        _serial_machine(tmp_path, "fanuc-2", serial % (4002, 4000)),
        _serial_machine(tmp_path, "fanuc-3", serial % (4003, 3000)),
    ]
    gw = tmp_path / "gateway.yaml"
    gw.write_text(f"machines: [{', '.join(files)}]\n")
    with pytest.raises(ConfigError) as info:
        load([gw], environ={})
    [issue] = info.value.issues
    assert issue.file.endswith("fanuc-3.yaml") and issue.key == "jobs.controller.link_capacity"
    assert "'nport-7'" in issue.message and "fanuc-1" in issue.message and "3000" in issue.message
    gw.write_text(f"machines: [{', '.join(files[:2])}]\n")
    config = load([gw], environ={})
    assert {m.jobs.controller.link for m in config.machines if m.jobs} == {"nport-7"}  # type: ignore[union-attr]


def test_a_link_capacity_names_its_link() -> None:
    with pytest.raises(ValidationError, match="link_capacity needs link"):
        JobsConfig.model_validate({"controller": {"type": "serial", "where": "COM3", "link_capacity": 100}})
    with pytest.raises(ValidationError, match="link"):
        JobsConfig.model_validate({"controller": {"type": "serial", "where": "COM3", "link": "a b"}})
