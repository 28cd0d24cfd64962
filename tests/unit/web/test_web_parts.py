"""The web console's pure parts: routing, who is asking (sessions, tokens, CSRF), live values (watches,
encoding, coalescing per page), the OpenAPI document, the http: section and its masked view."""

from __future__ import annotations

import asyncio
import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.auth.ratelimit import LoginLimiter
from gateway.auth.tokens import TokenStore
from gateway.auth.users import UserDirectory
from gateway.config.gateway import GatewayConfig
from gateway.errors import AccessDenied, MalformedRequest, UnknownVariable
from gateway.model.definitions import MachineDefinition, VariableDefinition
from gateway.model.sample import Sample
from gateway.model.tree import VariableTree
from gateway.model.types import TypeSpec
from gateway.settings.masking import MASK, masked
from gateway.sinks.web.http import HttpRequest
from gateway.sinks.web.live import Client, Live, encode, parse_watch, row
from gateway.sinks.web.openapi import document
from gateway.sinks.web.routes import Router
from gateway.sinks.web.sessions import COOKIE, LoginRequired, Sessions
from tests.waiting import wait_until


async def _handler() -> None:
    return None


def test_router_matches_segments_the_rest_and_says_which_methods_a_path_takes() -> None:
    r = Router()
    r.add("GET", "/api/machines/{machine}", _handler)
    r.add("GET", "/api/machines/{machine}/variables/{path*}", _handler)
    r.add("PUT", "/api/machines/{machine}/variables/{path*}", _handler)
    found = r.match("GET", "/api/machines/m1/variables/Axes/X/Position")
    assert isinstance(found, tuple) and found[1] == {"machine": "m1", "path": "Axes/X/Position"}
    assert r.match("DELETE", "/api/machines/m1/variables/A") == ["GET", "PUT"]
    assert r.match("GET", "/api/machines/m1/variables/") is None  # no path
    assert r.match("GET", "/api/machines//variables/A") is None  # no machine
    assert r.match("GET", "/api/other") is None
    head = r.match("HEAD", "/api/machines/m1")
    assert isinstance(head, tuple) and head[1] == {"machine": "m1"}


def _request(**kw: Any) -> HttpRequest:
    base: dict[str, Any] = {
        "method": "GET",
        "path": "/",
        "query": {},
        "headers": {},
        "cookies": {},
        "remote": "10.0.0.9",
    }
    base.update(kw)
    return HttpRequest(**base)


def _sessions(tmp_path: Path, *, anonymous: bool = True) -> Sessions:
    from gateway.auth.passwords import hash_password

    users = UserDirectory(
        {"olga": (hash_password("secret", n=2**10), "operator")},
        anonymous_role="viewer" if anonymous else None,
        anonymous_allowed=anonymous,
        limiter=LoginLimiter(2, 60, 300),
    )
    return Sessions(users, TokenStore(tmp_path / "tokens.json"), idle=3600)


async def test_a_login_makes_a_session_whose_unsafe_requests_need_its_csrf_token(tmp_path: Path) -> None:
    sessions = _sessions(tmp_path)
    assert await sessions.login("olga", "wrong", "10.0.0.9") is None
    session = await sessions.login("olga", "secret", "10.0.0.9")
    assert session is not None
    cookie = sessions.cookie(session, secure=True)
    assert (
        cookie.startswith(f"{COOKIE}={session.id};") and "HttpOnly" in cookie and "SameSite=Strict" in cookie
    )
    assert "Secure" in cookie and "Secure" not in sessions.cookie(session, secure=False)
    caller = sessions.caller(_request(cookies={COOKIE: session.id}))
    assert (caller.user, caller.role, caller.via) == ("olga", "operator", "session")
    sessions.check_csrf(_request(method="GET"), caller)  # safe methods need none
    with pytest.raises(AccessDenied, match="CSRF"):
        sessions.check_csrf(_request(method="PUT"), caller)
    with pytest.raises(AccessDenied, match="CSRF"):
        sessions.check_csrf(_request(method="POST", headers={"x-csrf-token": "guess"}), caller)
    sessions.check_csrf(_request(method="POST", headers={"x-csrf-token": session.csrf}), caller)
    sessions.check_csrf(_request(method="POST", form={"csrf": session.csrf}), caller)
    sessions.logout(caller)
    assert sessions.caller(_request(cookies={COOKIE: session.id})).via == "anonymous"


async def test_the_lockout_refuses_even_the_right_password(tmp_path: Path) -> None:
    sessions = _sessions(tmp_path)
    for _ in range(2):
        assert await sessions.login("olga", "wrong", "10.0.0.7") is None
    assert await sessions.login("olga", "secret", "10.0.0.7") is None
    assert await sessions.login("olga", "secret", "10.0.0.8") is not None  # per address


def test_tokens_act_with_their_users_current_role_and_are_kept_hashed(tmp_path: Path) -> None:
    sessions = _sessions(tmp_path, anonymous=False)
    token = sessions.tokens.create("olga", "grafana")
    stored = (tmp_path / "tokens.json").read_text()
    assert token.split("_", 2)[2] not in stored and (tmp_path / "tokens.json").stat().st_mode & 0o077 == 0
    caller = sessions.caller(_request(headers={"authorization": f"Bearer {token}"}))
    assert (caller.user, caller.role, caller.via) == ("olga", "operator", "token")
    sessions.check_csrf(_request(method="POST"), caller)  # no cookie, no CSRF token needed
    for bad in (token[:-1] + ("A" if token[-1] != "A" else "B"), "cgw_zz", "Basic abc"):
        with pytest.raises(LoginRequired):
            sessions.caller(_request(headers={"authorization": bad if " " in bad else f"Bearer {bad}"}))
    orphan = sessions.tokens.create("gone-user")
    with pytest.raises(LoginRequired, match="its user is gone"):
        sessions.caller(_request(headers={"authorization": f"Bearer {orphan}"}))
    with pytest.raises(LoginRequired, match="refuse"):
        sessions.caller(_request())  # anonymous visitors refused
    sessions.tokens.revoke(token.split("_")[1])
    with pytest.raises(LoginRequired):
        sessions.caller(_request(headers={"authorization": f"Bearer {token}"}))


def _tree() -> VariableTree:
    variables = tuple(
        VariableDefinition(p, TypeSpec.parse(t))
        for p, t in (("A/x", "Double"), ("A/y", "Int32"), ("S", "String"))
    )
    return VariableTree([MachineDefinition("m1", variables), MachineDefinition("m2", variables[:1])])


def test_a_watch_names_machines_or_paths_and_refuses_what_does_not_exist() -> None:
    tree = _tree()
    watch = parse_watch(tree, [{"machine": "m1", "paths": None}, {"machine": "*", "paths": ["A/x"]}])
    assert watch.machines == {"m1"} and {n.full_path for n in watch.nodes} == {"m1/A/x", "m2/A/x"}
    m2 = tree.machines["m2"]
    assert watch.wants(tree.machines["m1"].nodes["S"]) and watch.wants(m2.nodes["A/x"])
    assert not watch.wants(m2.nodes["Status/State"])
    assert len(watch.current(tree)) == len(tree.machines["m1"].nodes) + 1
    with pytest.raises(UnknownVariable):
        parse_watch(tree, [{"machine": "m3", "paths": None}])
    with pytest.raises(UnknownVariable, match="'B'"):
        parse_watch(tree, [{"machine": "m1", "paths": ["B"]}])
    parse_watch(tree, [{"machine": "*", "paths": ["S"]}])  # m2 lacks it: fine with "*"
    for bad in (
        "m1",
        [{"paths": None}],
        [{"machine": "m1", "paths": "A/x"}],
        [{"machine": "m1", "paths": [1]}],
    ):
        with pytest.raises(MalformedRequest):
            parse_watch(tree, bad)


values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**63), max_value=2**64),
    st.booleans(),
    st.text(),
    st.none(),
    st.lists(st.floats(allow_nan=False), max_size=5),
)


@given(value=values, status=st.sampled_from(["Good", "BadNotConnected", 'Uncertain"Odd']))
def test_the_hand_made_encoding_is_the_json_of_the_rows(value: Any, status: str) -> None:
    tree = _tree()
    node = tree.machines["m1"].nodes["A/x"]
    sample = Sample(value, datetime(2026, 5, 6, 7, 8, 9, 123000, tzinfo=UTC), status)
    decoded = json.loads(encode([(node, sample), (node, sample)]))
    assert decoded == {"v": [json.loads(json.dumps(row(node, sample)))] * 2}
    assert decoded["v"][0][4] == 1778051289123


async def test_a_page_that_lags_gets_its_changes_merged_per_variable() -> None:
    tree = _tree()
    a, b = tree.machines["m1"].nodes["A/x"], tree.machines["m1"].nodes["A/y"]
    ts = datetime.now(UTC)
    client = Client(socket=None)  # type: ignore[arg-type]
    first = [(a, Sample(1.0, ts))]
    client.offer(first, encode(first))
    assert client.ready == encode(first) and not client.pending  # shared, encoded once
    client.offer([(a, Sample(2.0, ts)), (b, Sample(5, ts))], "unused")  # not sent yet: merged
    assert client.ready is None and {n: s.value for n, s in client.pending.items()} == {a: 2.0, b: 5}
    client.offer([(a, Sample(3.0, ts))], "unused")
    assert {n: s.value for n, s in client.pending.items()} == {a: 3.0, b: 5}


def _page(live: Live, watch: Any) -> Client:
    """A page that sent `watch`, as `Live.serve` would register it (no socket: nothing is sent)."""
    client = Client(socket=None)  # type: ignore[arg-type]
    live.clients.add(client)
    live._message(client, json.dumps({"watch": watch}))
    return client


def _values(changes: list[Any]) -> dict[str, Any]:
    return {f"{n.machine.name}/{n.path}": s.value for n, s in changes}


async def test_the_pages_get_what_changed_among_what_they_watch_since_the_last_look() -> None:
    tree = _tree()
    m1, m2 = tree.machines["m1"], tree.machines["m2"]
    ts = datetime.now(UTC)
    live = Live(tree)
    _page(live, [{"machine": "m1", "paths": ["A/x"]}])
    assert live.changes() == []  # the page's snapshot has what is there now
    m1.ingest(m1.nodes["A/x"], 1.0, ts)
    m1.ingest(m1.nodes["A/x"], 2.0, ts)  # the latest per variable, as the hub's coalescing gave
    m1.ingest(m1.nodes["A/y"], 7, ts)  # not watched
    m2.ingest(m2.nodes["A/x"], 9.0, ts)  # nor is this machine
    assert _values(live.changes()) == {"m1/A/x": 2.0}
    assert live.changes() == []  # handed out once
    m1.ingest(m1.nodes["A/x"], 2.0, ts)  # the same value is no change (the tree publishes nothing)
    assert live.changes() == []
    assert not tree.hub.subscriptions  # nothing is paid per change while pages are looked at per tick


async def test_a_page_watching_anew_leaves_the_others_their_change_not_yet_looked_at() -> None:
    tree = _tree()
    m1 = tree.machines["m1"]
    ts = datetime.now(UTC)
    live = Live(tree)
    _page(live, [{"machine": "m1", "paths": ["A/x"]}])
    m1.ingest(m1.nodes["A/x"], 1.0, ts)
    second = _page(live, [{"machine": "m1", "paths": None}])  # the whole machine, between two looks
    assert _values(list(second.pending.items()))["m1/A/x"] == 1.0  # in its snapshot
    assert _values(live.changes()) == {"m1/A/x": 1.0}  # and still due to the first page
    m1.ingest(m1.nodes["A/y"], 3, ts)
    node = m1.add_internal("Status/Later", "Int32", "added after the watch", 5)
    assert _values(live.changes()) == {"m1/A/y": 3, "m1/Status/Later": 5}  # whole machine: new ones too
    live.clients.discard(second)
    live._rewatch()  # the second page goes: its variables are no longer looked at
    m1.ingest(m1.nodes["A/y"], 4, ts)
    m1.set_internal(node, 6)
    m1.ingest(m1.nodes["A/x"], 5.0, ts)
    assert _values(live.changes()) == {"m1/A/x": 5.0}


async def test_pages_without_a_watch_cost_the_hub_nothing_and_a_watch_wakes_the_ticker() -> None:
    tree = _tree()
    m1 = tree.machines["m1"]
    live = Live(tree, tick=0.01)
    ticker = asyncio.create_task(live.run())
    try:
        events_only = Client(socket=None)  # type: ignore[arg-type]
        live.clients.add(events_only)
        live._message(events_only, json.dumps({"events": True}))
        for n in range(50):
            m1.ingest(m1.nodes["A/x"], float(n), datetime.now(UTC))
            await asyncio.sleep(0)
        assert not tree.hub.subscriptions  # nothing watched: no doorbell either
        page = _page(live, [{"machine": "m1", "paths": ["A/x"]}])
        page.pending.clear()  # the snapshot, as the page's writer would have sent it
        m1.ingest(m1.nodes["A/x"], 99.0, datetime.now(UTC))
        await wait_until(lambda: page.ready is not None, message="the change handed to the page")
        assert page.ready is not None and '"A/x",99.0,' in page.ready
    finally:
        ticker.cancel()
        await asyncio.gather(ticker, return_exceptions=True)


def test_the_openapi_document_is_complete_and_every_reference_resolves() -> None:
    doc = document()
    assert doc["openapi"].startswith("3.1")
    text = json.dumps(doc)
    for ref in {part.split('"')[0] for part in text.split('"$ref": "')[1:]}:
        node: Any = doc
        for key in ref.removeprefix("#/").split("/"):
            node = node[key]
    for path, ops in doc["paths"].items():
        params = {p.split("}")[0] for p in path.split("{")[1:]}
        for op in ops.values():
            assert params == {p["name"] for p in op["parameters"] if p["in"] == "path"}, path
            assert any(code.startswith("2") for code in op["responses"])


def test_the_http_section_and_the_masked_configuration() -> None:
    assert GatewayConfig().http is not None and GatewayConfig().http.port == 8080  # type: ignore[union-attr]
    assert GatewayConfig.model_validate({"http": None}).http is None
    with pytest.raises(ValueError, match=r"http\.admin_role: 'root' is not a role"):
        GatewayConfig.model_validate({"http": {"admin_role": "root"}})
    config = GatewayConfig.model_validate(
        {"users": [{"name": "olga", "role": "operator", "password_hash": _hash()}]}
    )
    view = masked(config)
    assert view["users"][0]["password_hash"] == MASK and view["users"][0]["name"] == "olga"
    assert config.http is not None and config.http.admin(list(config.roles)) == "admin"


def _hash() -> str:
    from gateway.auth.passwords import hash_password

    return hash_password("x", n=2**10)


def test_the_masked_view_hides_a_password_in_a_url_and_keeps_the_rest() -> None:
    config = GatewayConfig.model_validate({"queue": "postgresql://gw:hunter2@db.plant:5432/jobs"})
    view = masked(config)
    assert view["queue"] == f"postgresql://gw:{MASK}@db.plant:5432/jobs"
    assert "hunter2" not in json.dumps(view)
