"""After a login the console goes back where the visitor was, and only there (issue 23, item 7): every `next`
of tests/corpus/http/redirects.yaml gets its Location, and a real browser (Chromium through Playwright)
that follows the issue's `next=/%09/evil.example/x` stays on the gateway. Before the fix the answer was
`Location: /\\t/evil.example/x`, which Chromium took to http://evil.example/x."""

from __future__ import annotations

from pathlib import Path
from typing import Any
from urllib.parse import quote, urlsplit

import aiohttp
import yaml

from tests.integration.drills.slow_http import lands_on
from tests.integration.web.conftest import USERS, WebRig

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "http" / "redirects.yaml"
EVIL = "evil.example"


async def test_every_next_of_the_corpus_gets_its_location_on_this_host(rig: WebRig) -> None:
    host = urlsplit(rig.url).netloc
    failures = []
    for case in yaml.safe_load(CORPUS.read_text(encoding="utf-8")):
        async with (
            aiohttp.ClientSession(base_url=rig.url) as session,
            session.post(
                "/login",
                data={"username": "otto", "password": USERS["otto"][1], "next": case["next"]},
                allow_redirects=False,
            ) as r,
        ):
            location = r.headers.get("Location", "")
            if (
                r.status != 303
                or location != case["location"]
                or lands_on(rig.url + "/login", location) != host
            ):
                failures.append(f"{case['name']}: HTTP {r.status}, Location {location!r}")
        async with (
            aiohttp.ClientSession(base_url=rig.url) as session,
            session.get("/login", params={"next": case["next"]}) as r,
        ):  # the login page carries only the cleaned value on to its form
            page = await r.text()
            if f'name="next" value="{case["location"]}"' not in page.replace("&amp;", "&"):
                failures.append(f"{case['name']}: the login page's next is not {case['location']!r}")
    assert not failures, "\n".join(failures)


async def test_a_browser_that_follows_the_issues_redirect_stays_on_the_gateway(
    rig: WebRig, browser: Any
) -> None:
    page = await browser.new_page()
    visited: list[str] = []

    async def elsewhere(route: Any) -> None:  # were the browser sent there, it would get this page
        visited.append(route.request.url)
        await route.fulfill(body="<h1 id=evil>evil</h1>", content_type="text/html")

    await page.route(f"**://{EVIL}/**", elsewhere)
    for trap in ("/%09/evil.example/x", "//evil.example/x", "/%5C" + EVIL, "/%5C%5C" + EVIL):
        await page.goto(f"{rig.url}/login?next={quote(trap, safe='/%')}")
        await page.fill("#username", "otto")
        await page.fill("#password", USERS["otto"][1])
        await page.click("#login-submit")
        await page.wait_for_load_state()
        assert urlsplit(page.url).netloc == urlsplit(rig.url).netloc, (trap, page.url)
        assert await page.locator("#me").text_content() is not None
    assert visited == []
