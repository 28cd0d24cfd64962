"""The console in a real browser (Debian's Chromium, through Playwright) against a gateway and simulator:
log in, watch a position change live, write as operator and be refused as viewer, drop a job and see it
DELIVERED, acknowledge an alarm raised through a command, trust a rejected OPC UA certificate, log out.

Every wait is for a condition (Playwright's expect / wait_for), never a fixed sleep.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from playwright.async_api import Page, expect

from tests.integration.security.test_endpoints import CLIENT_URI, client_certificate
from tests.integration.web.conftest import MACHINE, USERS, WebRig
from tests.opcua_client import Client

PART = "%\nO2002 (WEB PART)\nG21 G90\nG0 X20 Y20\nG1 X40 F6000\nG1 Y30\nM30\n%\n"
SCREENSHOTS = os.environ.get("CNC_SCREENSHOTS")  # a folder: also save the README's screenshots there


async def login(page: Page, rig: WebRig, user: str) -> None:
    await page.goto(rig.url + "/login")
    await page.fill("#username", user)
    await page.fill("#password", USERS[user][1])
    await page.click("#login-submit")
    await expect(page.locator("#me")).to_contain_text(user)


def var(page: Page, path: str) -> Any:
    return page.locator(f'tr[data-var="{MACHINE}/{path}"]')


async def call(page: Page, command: str, **args: str) -> Any:
    form = page.locator(f"#call-Commands-{command}")
    for key, value in args.items():
        await form.locator(f'input[name="{key}"]').fill(value)
    await form.locator("button[type=submit]").click()
    return form.locator(".answer")


async def test_live_values_writes_by_role_and_logout(rig: WebRig, browser: Any, tmp_path: Path) -> None:
    page = await browser.new_page(viewport={"width": 1400, "height": 900})
    await login(page, rig, "otto")
    await page.goto(f"{rig.url}/machines/{MACHINE}")
    await expect(page.locator("#live-state")).to_have_class("live on")
    x = var(page, "Axes/X/Position").locator(".v")
    await expect(x).not_to_have_text("")
    before = await x.text_content()

    # The operator runs the demo program with the command buttons: the position moves on the page.
    await expect(await call(page, "select-program", name="demo.nc")).to_contain_text("ok")
    await expect(await call(page, "start")).to_contain_text("ok")
    await expect(x).not_to_have_text(before or "")
    moved = await x.text_content()
    await expect(x).not_to_have_text(moved or "")  # and keeps moving, without a reload

    # The feed override: written by the operator, with the controller's value shown where it was made.
    row = var(page, "Feed/Override")
    await row.locator("input[name=value]").fill("60")
    await row.locator("button[type=submit]").click()
    await expect(row.locator(".answer")).to_have_text("ok: 60")
    await expect(row.locator(".v")).to_have_text("60")
    await row.locator("input[name=value]").fill("200")
    await row.locator("button[type=submit]").click()
    await expect(row.locator(".answer")).to_contain_text("BadOutOfRange")
    assert rig.machine.nodes["Feed/Override"].sample.value == 60

    shots = Path(SCREENSHOTS) if SCREENSHOTS else tmp_path
    await page.evaluate("window.scrollTo(0, 0)")
    await page.screenshot(path=str(shots / "console-machine.png"))
    await page.goto(rig.url + "/")
    await expect(page.locator(f'tr[data-machine="{MACHINE}"] td.link .v')).to_have_text("connected")
    await page.set_viewport_size({"width": 1400, "height": 300})
    await page.screenshot(path=str(shots / "console-machines.png"))
    for name in ("console-machine.png", "console-machines.png"):
        assert (shots / name).read_bytes().startswith(b"\x89PNG")

    await page.click("#logout")
    await expect(page).to_have_url(rig.url + "/login")
    await page.goto(f"{rig.url}/machines/{MACHINE}")
    await expect(page.locator("#me")).to_contain_text("anonymous")

    # A viewer gets no input for it, and a write sent from the viewer's page anyway is refused.
    await login(page, rig, "vera")
    await page.goto(f"{rig.url}/machines/{MACHINE}")
    row = var(page, "Feed/Override")
    await expect(row.locator("td.w")).to_have_text("operator")
    assert await row.locator("input").count() == 0
    answer = await page.evaluate(
        """async () => {
            const csrf = document.querySelector('meta[name="csrf"]').content;
            const r = await fetch('/api/machines/laser-sim/variables/Feed/Override', {method: 'PUT',
                headers: {'Content-Type': 'application/json', 'X-CSRF-Token': csrf}, body: '{"value": 10}'});
            return {status: r.status, body: await r.json()};
        }"""
    )
    assert answer["status"] == 403
    assert answer["body"]["error"]["status"] == "BadUserAccessDenied"
    assert "needs 'operator'" in answer["body"]["error"]["reason"]
    assert rig.machine.nodes["Feed/Override"].sample.value == 60

    # The viewer has no audit page (nor a link to it); the admin's shows both, with origin http.
    assert await page.locator('nav a[href="/audit"]').count() == 0
    refused = await page.goto(f"{rig.url}/audit?origin=http&kind=write")
    assert refused is not None and refused.status == 403
    await expect(page.locator("main")).to_contain_text("may not read the audit trail")
    await page.click("#logout")
    await login(page, rig, "ada")
    await page.click('nav a[href="/audit"]')
    await page.goto(f"{rig.url}/audit?origin=http&kind=write")
    table = page.locator("#audit")
    await expect(table).to_contain_text("vera@http/viewer")
    await expect(table).to_contain_text("BadUserAccessDenied")
    await expect(table).to_contain_text("otto@http/operator")
    await page.click("#logout")
    await expect(page).to_have_url(rig.url + "/login")


async def test_alarm_acknowledged_and_job_dropped_until_delivered(rig: WebRig, browser: Any) -> None:
    page = await browser.new_page(viewport={"width": 1400, "height": 900})
    await login(page, rig, "otto")

    # Commands that raise an alarm on the controller: a program that leaves the machine's travel.
    await page.goto(f"{rig.url}/machines/{MACHINE}")
    await expect(await call(page, "select-program", name="soft-limit.nc")).to_contain_text("ok")
    await expect(await call(page, "start")).to_contain_text("ok")
    await page.goto(rig.url + "/alarms")
    row = page.locator("#active-alarms tr.alarm.active").first
    await expect(row).to_contain_text("limit", timeout=15_000)
    await row.locator('input[name="comment"]').fill("seen, wrong name")
    await row.locator("button[type=submit]").click()
    await expect(row.locator(".alarm-state")).to_contain_text("acknowledged by otto")
    manager = rig.gateway.alarms.managers[MACHINE]  # type: ignore[union-attr]
    assert all(r.acked_by == "otto" and r.ack_comment == "seen, wrong name" for r in manager.records.values())

    # A program dropped on the jobs page goes through the inbox's validation and queue to the controller.
    await page.goto(rig.url + "/jobs")
    transfer = await page.evaluate_handle(
        """(text) => {
            const dt = new DataTransfer();
            dt.items.add(new File([text], 'web-part.nc', {type: 'text/plain'}));
            return dt;
        }""",
        PART,
    )
    await page.dispatch_event("#dropzone", "dragenter", {"dataTransfer": transfer})
    await page.dispatch_event("#dropzone", "drop", {"dataTransfer": transfer})
    await expect(page.locator("#upload-answer")).to_contain_text("queued for laser-sim")
    job = page.locator("tr.job", has_text="web-part.nc").first
    await expect(job.locator(".state")).to_have_text("DELIVERED", timeout=30_000)
    assert (rig.sim.programs.programs / "web-part.nc").read_text().startswith("%")


async def test_certificate_moves_from_rejected_to_trusted(rig: WebRig, browser: Any, tmp_path: Path) -> None:
    cert, key = client_certificate(tmp_path / "clients", "night-shift-hmi")

    async def connect() -> None:
        client = Client(rig.opcua, timeout=5)
        client.application_uri = CLIENT_URI
        await client.set_security(
            SecurityPolicyBasic256Sha256,
            str(cert),
            str(key),
            server_certificate=str(rig.state_dir / "pki" / "own" / "cert.der"),
            mode=ua.MessageSecurityMode.SignAndEncrypt,
        )
        async with client:
            await client.get_node(f"ns=2;s={MACHINE}/Feed/Override").read_browse_name()

    with pytest.raises(ua.uaerrors.BadCertificateUntrusted):
        await connect()

    page = await browser.new_page()
    await login(page, rig, "ada")
    await page.goto(rig.url + "/gateway")
    row = page.locator("tr.cert", has_text="night-shift-hmi")
    await expect(row.locator(".cert-state")).to_have_text("rejected")
    await row.locator("button.cert-action").click()
    await expect(row.locator(".cert-state")).to_have_text("trusted")
    await connect()  # the next attempt is accepted, without a restart

    # An operator sees the list but no buttons; the API refuses the operator too.
    session = await rig.session("otto")
    async with session.post("/api/gateway/certificates/anything.der/trust") as r:
        assert r.status == 403
        assert (await r.json())["error"]["status"] == "BadUserAccessDenied"
