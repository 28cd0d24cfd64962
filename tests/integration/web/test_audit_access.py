"""The audit trail (every user's name and every change) is for `http.audit_role`, the admin role unless the
gateway file names another (issue 23, item 12): the API and the page refuse the others (anonymous visitors
and viewers included), and the navigation shows the page only to those who may read it."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.config.gateway import GatewayConfig
from tests.integration.web.conftest import WebRig, web_gateway


async def statuses(rig: WebRig) -> dict[str, tuple[int, int, bool]]:
    """Per caller: /api/audit's status, /audit's status, and whether the menu links to it."""
    out = {}
    for user in (None, "vera", "otto", "ada"):
        session = await rig.session(user)
        async with session.get("/api/audit?limit=5") as api:
            if api.status == 200:
                assert "entries" in await api.json()
        async with session.get("/audit") as page:
            await page.read()
        async with session.get("/") as home:
            linked = 'href="/audit"' in await home.text()
        out[user or "anonymous"] = (api.status, page.status, linked)
    return out


async def test_only_the_admin_reads_the_audit_trail_by_default(rig: WebRig) -> None:
    assert await statuses(rig) == {
        "anonymous": (403, 403, False),
        "vera": (403, 403, False),
        "otto": (403, 403, False),
        "ada": (200, 200, True),
    }


async def test_audit_role_names_who_may(tmp_path: Path) -> None:
    async with web_gateway(tmp_path, http={"audit_role": "operator"}) as rig:
        assert await statuses(rig) == {
            "anonymous": (403, 403, False),
            "vera": (403, 403, False),
            "otto": (200, 200, True),
            "ada": (200, 200, True),
        }


def test_an_audit_role_that_is_not_a_role_is_a_config_error() -> None:
    with pytest.raises(ValueError, match=r"http.audit_role: 'auditor' is not a role"):
        GatewayConfig.model_validate({"http": {"audit_role": "auditor"}})
