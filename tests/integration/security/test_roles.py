"""Viewer, operator and engineer log in over OPC UA and try the same writes and calls: each gets what its
role allows, sees a UserAccessLevel that says so, and the audit table (and `cnc-gateway audit list`)
shows all of it. Anonymous clients are viewers; wrong passwords are refused and, repeated, locked out."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from gateway.audit.store import AuditStore, audit_path
from tests.integration.security.conftest import MACHINE, USERS, Rig, secure_gateway
from tests.opcua_client import Client
from tests.waiting import wait_until

WRITE = ua.AccessLevel.CurrentWrite.mask
ROOT = Path(__file__).resolve().parents[3]


def node(client: Client, path: str) -> Any:
    return client.get_node(f"ns=2;s={MACHINE}/{path}")


async def status_of(coro: Any) -> str:
    try:
        await coro
    except ua.UaStatusCodeError as exc:
        return type(exc).__name__
    return "Good"


async def user_access(client: Client, path: str) -> int:
    return (await node(client, path).read_attribute(ua.AttributeIds.UserAccessLevel)).Value.Value


async def user_executable(client: Client, path: str) -> bool:
    return (await node(client, path).read_attribute(ua.AttributeIds.UserExecutable)).Value.Value


async def attempt(rig: Rig, client: Client, override: int) -> dict[str, Any]:
    """The same writes and calls, whoever the client is."""
    programs = node(client, "Programs")
    return {
        "override_level": bool(await user_access(client, "Feed/Override") & WRITE),
        "mode_level": bool(await user_access(client, "Machine/Mode") & WRITE),
        "delete_executable": await user_executable(client, "Programs/Delete"),
        "list_executable": await user_executable(client, "Programs/List"),
        "override": await status_of(
            node(client, "Feed/Override").write_value(ua.Variant(override, ua.VariantType.UInt16))
        ),
        "mode": await status_of(
            node(client, "Machine/Mode").write_value(ua.Variant(0, ua.VariantType.Int16))
        ),
        "delete": await status_of(
            programs.call_method("2:Delete", ua.Variant("gone.nc", ua.VariantType.String))
        ),
        "put": await status_of(
            programs.call_method(
                "2:Put", ua.Variant("t.nc", ua.VariantType.String), ua.Variant("M30\n", ua.VariantType.String)
            )
        )
        if override == 41
        else None,
    }


async def test_each_role_may_do_what_it_may_and_the_audit_shows_all_of_it(tmp_path: Path) -> None:
    async with secure_gateway(tmp_path) as rig:
        await wait_until(
            lambda: rig.machine.nodes["Feed/Override"].sample.good, timeout=15, message="override Good"
        )
        seen: dict[str, dict[str, Any]] = {}
        for index, user in enumerate([None, "vera", "otto", "erik"]):
            client = rig.client(user)
            async with client:
                seen[user or "anonymous"] = await attempt(rig, client, 40 + index)
        await rig.gateway.audit.flush()
        rows = AuditStore(audit_path(rig.state_dir)).query(machine=MACHINE, limit=1000)

    denied = "BadUserAccessDenied"
    for who in ("anonymous", "vera"):  # anonymous logins are viewers
        assert seen[who]["override"] == seen[who]["mode"] == seen[who]["delete"] == denied, who
        assert not seen[who]["override_level"] and not seen[who]["mode_level"]
        assert not seen[who]["delete_executable"] and seen[who]["list_executable"]
    assert seen["vera"]["put"] == denied
    assert (seen["otto"]["override"], seen["otto"]["mode"]) == ("Good", denied)
    assert (
        seen["otto"]["override_level"]
        and not seen["otto"]["mode_level"]
        and seen["otto"]["delete_executable"]
    )
    assert seen["erik"]["override"] == seen["erik"]["mode"] == "Good"
    assert seen["erik"]["override_level"] and seen["erik"]["mode_level"]
    for who in (
        "otto",
        "erik",
    ):  # allowed: the call reaches the simulator's program store, which has no such file
        assert seen[who]["delete"] == "BadNotFound", who

    def row(user: str | None, target: str) -> Any:
        found = [r.entry for r in rows if r.entry.user == user and r.entry.target == target]
        assert len(found) == 1, (user, target, [r.entry for r in rows])
        return found[0]

    refused = row("vera", "Feed/Override")
    assert (refused.status, refused.role, refused.origin, refused.new) == (denied, "viewer", "opcua", "41")
    assert "role 'viewer' may not write laser-sim/Feed/Override" in refused.reason
    written = row("otto", "Feed/Override")
    assert (written.kind, written.status, written.role, written.old, written.new) == (
        "write",
        "Good",
        "operator",
        "100",
        "42",
    )
    assert row(None, "Feed/Override").role == "viewer"
    assert row("otto", "Machine/Mode").status == denied and row("erik", "Machine/Mode").status == "Good"
    call = row("vera", "Programs.Delete")
    assert (call.kind, call.status, call.new) == ("call", denied, '["gone.nc"]')
    assert row("erik", "Programs.Delete").status == "BadNotFound"
    assert row("vera", "Programs.Put").status == denied

    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "gateway.cli.main",
            "audit",
            "list",
            "--state-dir",
            str(rig.state_dir),
            "--user",
            "otto",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    lines = [line for line in out.stdout.splitlines() if "Feed/Override" in line]
    assert len(lines) == 1 and "otto" in lines[0] and "100 -> 42" in lines[0] and "ok" in lines[0]
    assert any("Machine/Mode" in line and denied in line for line in out.stdout.splitlines())
    assert "vera" not in out.stdout


async def test_wrong_passwords_are_refused_and_repeated_ones_lock_the_address_out(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gateway.auth")
    lockout = {"failures": 3, "window": 60, "duration": 300}
    async with secure_gateway(
        tmp_path, simulator=False, gateway={"access": {"anonymous": "refuse", "lockout": lockout}}
    ) as rig:
        with pytest.raises(ua.UaError) as anonymous:
            async with rig.client():
                pass
        assert "BadIdentityTokenRejected" in repr(anonymous.value) or "BadUserAccessDenied" in repr(
            anonymous.value
        )

        async with rig.client("otto") as client:  # the right password, before any failure
            assert await user_access(client, "Feed/Override") & WRITE
        for attempt_no in range(3):
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                async with rig.client("otto", f"guess-{attempt_no}"):
                    pass
        assert "refusing every login from 127.0.0.1 for 300 s" in caplog.text
        with pytest.raises(ua.uaerrors.BadUserAccessDenied):  # now even the right password is turned away
            async with rig.client("otto", USERS["otto"][1]):
                pass
        assert "login as 'otto' from 127.0.0.1 refused unchecked: locked out" in caplog.text
        assert "guess" not in caplog.text  # passwords never reach the log
