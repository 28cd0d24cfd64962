"""Programs.Backup through each door that offers it (OPC UA's method node, the REST API's method call; MQTT
and Sparkplug offer only Commands): viewers and anonymous callers are refused, an operator's copy is
named without the server's path, the rate (jobs.backups.per_hour) and the retention (jobs.backups.keep)
hold, and the audit trail has every attempt (issue 23, item 11)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import aiohttp
from asyncua import ua

from gateway.audit.store import AuditStore, audit_path
from gateway.auth.tokens import TokenStore, tokens_path
from tests.integration.security.conftest import MACHINE, Rig, secure_gateway
from tests.waiting import free_port, wait_until

COPY = r"^\d{8}T\d{6}Z-(\d+-)?demo\.nc$"


async def opcua_backup(rig: Rig, user: str | None) -> tuple[str, Any]:
    async with rig.client(user) as client:
        programs = client.get_node(f"ns=2;s={MACHINE}/Programs")
        try:
            return "Good", await programs.call_method(
                "2:Backup", ua.Variant("demo.nc", ua.VariantType.String)
            )
        except ua.UaStatusCodeError as exc:
            return type(exc).__name__, None


async def rest_backup(url: str, token: str | None) -> tuple[int, Any]:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    async with (
        aiohttp.ClientSession() as session,
        session.post(
            f"{url}/api/machines/{MACHINE}/methods/Programs/Backup",
            json={"args": ["demo.nc"]},
            headers=headers,
        ) as r,
    ):
        return r.status, await r.json()


async def test_backup_needs_an_operator_names_no_path_and_keeps_its_rate_and_retention(
    tmp_path: Path,
) -> None:
    http = free_port()
    settings = {"http": {"host": "127.0.0.1", "port": http}}
    async with secure_gateway(tmp_path, gateway=settings) as rig:
        await wait_until(lambda: rig.machine.status.is_connected, timeout=15, message="connected")
        folder = rig.state_dir / "backups" / MACHINE
        url = f"http://127.0.0.1:{http}"
        tokens = TokenStore(tokens_path(rig.state_dir))
        vera, otto = tokens.create("vera", "tests"), tokens.create("otto", "tests")

        refused = {
            "opcua anonymous": (await opcua_backup(rig, None))[0],
            "opcua viewer": (await opcua_backup(rig, "vera"))[0],
            "rest anonymous": (await rest_backup(url, None))[0],
            "rest viewer": (await rest_backup(url, vera))[0],
        }
        assert not folder.exists() or not any(folder.iterdir()), list(folder.iterdir())

        jobs = rig.gateway.config.mappings[MACHINE].jobs
        assert jobs is not None and (jobs.backups.keep, jobs.backups.per_hour) == (50, 30)  # the defaults
        shelf_settings = jobs.backups.model_copy(update={"keep": 2, "per_hour": 4})
        rig.gateway.jobs.shelves[MACHINE].settings = shelf_settings
        status, name = await opcua_backup(rig, "otto")
        made = [name]
        for _ in range(3):
            code, body = await rest_backup(url, otto)
            assert code == 200, body
            made.append(body["outputs"]["File"])
        over_rest = await rest_backup(url, otto)
        over_opcua = (await opcua_backup(rig, "otto"))[0]
        kept = sorted(p.name for p in folder.iterdir())
        demo = (tmp_path / "store" / "DATA" / "Programs" / "demo.nc").read_bytes()
        await rig.gateway.audit.flush()
        rows = AuditStore(audit_path(rig.state_dir)).query(machine=MACHINE, limit=1000)

    assert refused == dict.fromkeys(
        ("opcua anonymous", "opcua viewer"), "BadUserAccessDenied"
    ) | dict.fromkeys(("rest anonymous", "rest viewer"), 403)
    assert status == "Good"
    assert all(isinstance(n, str) and "/" not in n and str(tmp_path) not in n for n in made), made
    assert all(re.match(COPY, n) for n in made), made
    assert over_rest[0] == 429 and over_rest[1]["error"]["status"] == "BadTooManyOperations"
    assert "at most 4 backups an hour" in over_rest[1]["error"]["reason"]
    assert over_opcua == "BadTooManyOperations"
    assert kept == sorted(made[-2:])  # the newest two of four
    assert all((folder / n).read_bytes() == demo for n in kept)
    calls = [
        (r.entry.user, r.entry.origin, r.entry.status) for r in rows if r.entry.target == "Programs.Backup"
    ]
    assert (None, "opcua", "BadUserAccessDenied") in calls and (
        "vera",
        "http",
        "BadUserAccessDenied",
    ) in calls
    assert calls.count(("otto", "opcua", "Good")) + calls.count(("otto", "http", "Good")) == 4
    assert ("otto", "http", "BadTooManyOperations") in calls and (
        "otto",
        "opcua",
        "BadTooManyOperations",
    ) in calls
