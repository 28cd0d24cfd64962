"""Uploads to the console are checked before their body is read (issue 23, item 2): the route, the caller and
the caller's role answer first, nothing is spooled for a refused request, at most `http.max_uploads` are
received at once, and a body that stalls is refused after `http.body_timeout`.

Each case of tests/corpus/http/spooling.yaml is sent with a 16 MiB Content-Length of which only the headers
and 256 KiB go out (drills/slow_http.held_upload): the answer must come while the rest is held back, and the
job inbox's staging folder must stay empty. Before the fix each of them was spooled (one held request wrote
16 files, 15.7 MB) and answered only once its whole body was in."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest
import yaml
from yarl import URL

from gateway.auth.tokens import TokenStore, tokens_path
from tests.integration.drills.slow_http import BOUNDARY, count_files, held_upload
from tests.integration.web.conftest import MACHINE, WebRig, web_gateway
from tests.waiting import wait_until

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "http" / "spooling.yaml"
PART = b"%\nO2003 (UPLOAD)\nG21 G90\nG0 X10 Y10\nG1 X30 F3000\nM30\n%\n"


def port_of(rig: WebRig) -> int:
    return int(rig.url.rsplit(":", 1)[1])


def staging(rig: WebRig) -> Path:
    return rig.state_dir / "inbox" / ".staging"


async def auth_headers(rig: WebRig) -> dict[str, dict[str, str]]:
    """Raw request headers for each kind of caller of the corpus."""
    out: dict[str, dict[str, str]] = {"anonymous": {}}
    for user in ("vera", "otto"):
        session = await rig.session(user)
        cookies = session.cookie_jar.filter_cookies(URL(rig.url))
        out[user] = {
            "Cookie": "; ".join(f"{k}={v.value}" for k, v in cookies.items()),
            "X-CSRF-Token": str(session.headers["X-CSRF-Token"]),
        }
    out["token"] = {
        "Authorization": f"Bearer {TokenStore(tokens_path(rig.state_dir)).create('otto', 'tests')}"
    }
    out["bad-token"] = {"Authorization": "Bearer cgw_00000000_" + "x" * 43}
    return out


async def run_corpus(rig: WebRig, port: int, *, refused: bool) -> list[str]:
    auth = await auth_headers(rig)
    failures = []
    for case in yaml.safe_load(CORPUS.read_text(encoding="utf-8")):
        headers = dict(auth[case.get("as", "anonymous")])
        if case.get("csrf") is False:
            headers.pop("X-CSRF-Token", None)
        want = str(case.get("refused", case["expect"]) if refused else case["expect"])
        held = await held_upload(
            port, case["path"], staging(rig), headers=headers, method=case.get("method", "POST")
        )
        if held.status != want or held.staged:
            failures.append(f"{case['name']}: {held} (expected {want}, nothing staged)")
    return failures


@pytest.fixture
async def refusing(tmp_path: Path) -> AsyncIterator[tuple[WebRig, int]]:
    """The console with `access.anonymous: refuse`, two uploads at a time, bodies that may stall 1 s."""
    http = {"max_uploads": 2, "body_timeout": 1.0}
    async with web_gateway(tmp_path, http=http, access={"anonymous": "refuse"}) as rig:
        yield rig, port_of(rig)


async def test_every_refused_upload_is_answered_before_its_body_and_spools_nothing(rig: WebRig) -> None:
    failures = await run_corpus(rig, port_of(rig), refused=False)
    assert not failures, "\n".join(failures)
    assert count_files(staging(rig)) == 0


async def test_with_anonymous_refused_too(refusing: tuple[WebRig, int]) -> None:
    rig, port = refusing
    failures = await run_corpus(rig, port, refused=True)
    assert not failures, "\n".join(failures)
    assert count_files(staging(rig)) == 0


async def test_uploads_beyond_max_uploads_are_refused_and_a_stalled_body_times_out(
    refusing: tuple[WebRig, int],
) -> None:
    rig, port = refusing
    otto = await rig.session("otto")
    headers = (await auth_headers(rig))["otto"]
    # Two uploads under way (their bodies held back): the staging folder has them, a third is refused.
    first = asyncio.create_task(held_upload(port, "/api/jobs", staging(rig), headers=headers, wait=8.0))
    second = asyncio.create_task(held_upload(port, "/api/jobs", staging(rig), headers=headers, wait=8.0))
    await wait_until(lambda: count_files(staging(rig)) == 2, message="two uploads spooling")
    third = await held_upload(port, "/api/jobs", staging(rig), headers=headers)
    assert third.status == "429" and third.staged == 2
    # The two held ones stall: refused after body_timeout (1 s), their partial files removed.
    stalled = await asyncio.gather(first, second)
    assert [h.status for h in stalled] == ["408", "408"]
    await wait_until(lambda: count_files(staging(rig)) == 0, message="the stalled uploads' files removed")
    # And a whole upload goes through.
    form = aiohttp.FormData({"machine": MACHINE})
    form.add_field("file", PART, filename="after.nc")
    async with otto.post("/api/jobs", data=form) as r:
        body = await r.json()
    assert r.status == 201 and body["ok"], body


async def test_expect_100_continue_is_answered_after_the_caller_is_checked(
    refusing: tuple[WebRig, int],
) -> None:
    rig, port = refusing
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:  # anonymous (refused here): the refusal comes instead of "100 Continue"
        writer.write(
            f"POST /api/jobs HTTP/1.1\r\nHost: t\r\nExpect: 100-continue\r\nContent-Length: 1000000\r\n"
            f"Content-Type: multipart/form-data; boundary={BOUNDARY}\r\n\r\n".encode()
        )
        line = await asyncio.wait_for(reader.readline(), 5)
    finally:
        writer.close()
    assert line.startswith(b"HTTP/1.1 401 ")
    otto = await rig.session("otto")
    form = aiohttp.FormData({"machine": MACHINE})
    form.add_field("file", PART, filename="continued.nc")
    async with otto.post("/api/jobs", data=form, expect100=True) as r:
        answer: Any = await r.json()
    assert r.status == 201 and answer["ok"], answer
    assert count_files(staging(rig)) == 0
