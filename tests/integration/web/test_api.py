"""The REST API, /metrics, health and the live socket over real HTTP against a gateway and simulator:
reads, writes and calls with the same checks and status names as OPC UA, the audit trail with origin http,
API tokens, the login lockout, the OpenAPI document, and the bad-input corpus (tests/corpus/http/)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest
import pytest_asyncio
import yaml

from gateway.auth.tokens import TokenStore, tokens_path
from gateway.cli.main import main as cli
from gateway.sinks.web.openapi import document
from tests.integration.web.conftest import MACHINE, USERS, WebRig, web_gateway
from tests.waiting import wait_until

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "http"

pytestmark = pytest.mark.asyncio(loop_scope="module")


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def api(tmp_path_factory: pytest.TempPathFactory) -> AsyncIterator[WebRig]:
    async with web_gateway(tmp_path_factory.mktemp("web-api")) as rig:
        yield rig


def _body(case: dict[str, Any], key: str = "body") -> bytes | None:
    if "parts" in case:
        return "".join(p["text"] * p.get("times", 1) for p in case["parts"]).encode()
    if f"{key}_hex" in case:
        return bytes.fromhex(case[f"{key}_hex"].replace(" ", ""))
    if key in case:
        return str(case[key]).encode()
    return None


def _cases(name: str) -> list[dict[str, Any]]:
    return yaml.safe_load((CORPUS / name).read_text(encoding="utf-8"))  # type: ignore[no-any-return]


async def _token(rig: WebRig, user: str) -> str:
    return TokenStore(tokens_path(rig.state_dir)).create(user, "tests")


async def test_every_corpus_request_gets_its_refusal(api: WebRig) -> None:
    sessions = {user: await api.session(user) for user in ("vera", "otto", "ada")}
    plain = await api.session(None)
    token = await _token(api, "otto")
    failures = []
    for case in _cases("requests.yaml"):
        who = case.get("as", "otto")
        session = sessions.get(who, plain)
        headers = dict(case.get("headers", {}))
        if who == "token":
            headers["Authorization"] = f"Bearer {token}"
        elif who == "bad-token":
            headers["Authorization"] = "Bearer cgw_00000000_" + "x" * 43
        if case.get("csrf") is False:
            headers["X-CSRF-Token"] = headers.get("X-CSRF-Token", "")
        if "content_type" in case:
            headers["Content-Type"] = case["content_type"]
        async with session.request(case["method"], case["path"], data=_body(case), headers=headers) as r:
            text = await r.text()
            expect = case["expect"]
            problems = []
            if r.status != expect["http"]:
                problems.append(f"HTTP {r.status}, expected {expect['http']}")
            if r.status >= 500:
                problems.append("a server error")
            if "status" in expect:
                try:
                    error = json.loads(text)["error"]
                except (ValueError, KeyError, TypeError):
                    error = {"status": None, "reason": text[:200]}
                if error["status"] != expect["status"]:
                    problems.append(f"status {error['status']}, expected {expect['status']}")
                if expect.get("reason", "") not in error["reason"]:
                    problems.append(f"reason {error['reason']!r} lacks {expect['reason']!r}")
            if "html" in expect and expect["html"] not in text:
                problems.append(f"the page lacks {expect['html']!r}")
            if "Traceback" in text:
                problems.append("a traceback")
            if problems:
                failures.append(f"{case['name']}: {'; '.join(problems)} ({text[:200]!r})")
    assert not failures, "\n".join(failures)
    async with sessions["otto"].get("/api/machines") as r:  # and the API still answers
        assert r.status == 200


async def _good_watch(ws: aiohttp.ClientWebSocketResponse) -> None:
    await ws.send_str(json.dumps({"watch": [{"machine": MACHINE, "paths": ["Status/State"]}]}))
    msg = await ws.receive(timeout=10)
    assert json.loads(msg.data)["v"][0][:2] == [MACHINE, "Status/State"]


async def test_every_corpus_live_message_gets_its_refusal(api: WebRig) -> None:
    session = await api.session("vera")
    ws = await session.ws_connect("/api/live")
    try:
        for case in _cases("live.yaml"):
            expect = case["expect"]
            if "message_hex" in case:
                await ws.send_bytes(bytes.fromhex(case["message_hex"].replace(" ", "")))
            else:
                await ws.send_str((_body(case, "message") or b"").decode())
            msg = await ws.receive(timeout=10)
            if "close" in expect:
                assert msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED), case["name"]
                assert ws.close_code == expect["close"], case["name"]
                ws = await session.ws_connect("/api/live")
            else:
                error = json.loads(msg.data)["error"]
                assert error["status"] == expect["status"], (case["name"], error)
                assert expect["reason"] in error["reason"], (case["name"], error)
            await _good_watch(ws)  # the socket still works
            await ws.send_str(json.dumps({"watch": []}))
    finally:
        await ws.close()


async def test_reads_writes_and_calls_by_token_are_audited_as_http(api: WebRig) -> None:
    token = await _token(api, "otto")
    session = await api.session(None)
    auth = {"Authorization": f"Bearer {token}"}
    async with session.get("/api/me", headers=auth) as r:
        assert await r.json() == {"user": "otto", "role": "operator", "via": "token"}
    async with session.get(f"/api/machines/{MACHINE}/variables/Axes/X/Position", headers=auth) as r:
        one = await r.json()
    assert one["unit"] == "mm" and one["quality"] == "good" and one["writable"] is False
    async with session.get(
        f"/api/machines/{MACHINE}/variables?path=Feed/Override&path=Machine/State", headers=auth
    ) as r:
        assert [v["path"] for v in (await r.json())["variables"]] == ["Feed/Override", "Machine/State"]
    async with session.get(f"/api/machines/{MACHINE}/variables?prefix=Axes/X", headers=auth) as r:
        paths = [v["path"] for v in (await r.json())["variables"]]
    assert paths and all(p.startswith("Axes/X/") for p in paths)

    # A write answered once the controller's value is in the tree (read-your-writes), as for OPC UA.
    async with session.put(
        f"/api/machines/{MACHINE}/variables/Feed/Override", json={"value": 42}, headers=auth
    ) as r:
        body = await r.json()
    assert r.status == 200 and body["variable"]["value"] == 42
    assert api.machine.nodes["Feed/Override"].sample.value == 42
    assert api.sim.machine.override == 42

    async with session.post(
        f"/api/machines/{MACHINE}/methods/Commands/select-program",
        json={"args": {"name": "demo.nc"}, "deadline": 10},
        headers=auth,
    ) as r:
        called = await r.json()
    assert r.status == 200, called
    assert "demo.nc" in json.dumps(called["outputs"]) and called["duration"] > 0
    async with session.post(f"/api/machines/{MACHINE}/methods/Programs/List", headers=auth) as r:
        listed = await r.json()
    assert "demo.nc" in json.dumps(listed["outputs"])

    await api.gateway.audit.flush()
    async with session.get("/api/audit?origin=http&user=otto&limit=50", headers=auth) as r:
        assert r.status == 403  # the audit trail is the admin's (http.audit_role)
    admin = {"Authorization": f"Bearer {await _token(api, 'ada')}"}
    async with session.get("/api/audit?origin=http&user=otto&limit=50", headers=admin) as r:
        entries = (await r.json())["entries"]
    kinds = {(e["kind"], e["target"], e["status"]) for e in entries}
    assert ("write", "Feed/Override", "Good") in kinds
    assert ("call", "Commands.select-program", "Good") in kinds
    assert all(e["origin"] == "http" and e["role"] == "operator" for e in entries)

    # Revoked, the token no longer opens anything.
    TokenStore(tokens_path(api.state_dir)).revoke(token.split("_")[1])
    async with session.get("/api/me", headers=auth) as r:
        assert r.status == 401


async def test_alarm_acknowledged_through_the_api(api: WebRig) -> None:
    otto = await api.session("otto")
    for name, args in (("reset", {}), ("select-program", {"name": "soft-limit.nc"}), ("start", {})):
        async with otto.post(f"/api/machines/{MACHINE}/methods/Commands/{name}", json={"args": args}) as r:
            assert r.status == 200, await r.text()

    async def active() -> list[dict[str, Any]]:
        async with otto.get(f"/api/alarms?machine={MACHINE}") as r:
            return [a for a in (await r.json())["active"] if a["active"] and not a["acked"]]

    [alarm] = await wait_until(active, timeout=15, message="the soft-limit alarm")
    vera = await api.session("vera")
    async with vera.post(f"/api/alarms/{MACHINE}/{alarm['occurrence']}/acknowledge", json={}) as r:
        assert r.status == 403 and (await r.json())["error"]["status"] == "BadUserAccessDenied"
    async with otto.post(
        f"/api/alarms/{MACHINE}/{alarm['occurrence']}/acknowledge", json={"comment": "checked"}
    ) as r:
        acked = (await r.json())["alarm"]
    assert acked["acked_by"] == "otto" and acked["ack_comment"] == "checked"
    async with otto.post(f"/api/alarms/{MACHINE}/{alarm['occurrence']}/acknowledge", json={}) as r:
        assert r.status == 409 and (await r.json())["error"]["status"] == "BadConditionBranchAlreadyAcked"
    async with otto.post(f"/api/machines/{MACHINE}/methods/Commands/reset", json={}) as r:
        assert r.status == 200


async def test_jobs_submitted_listed_shown_and_operated(api: WebRig) -> None:
    otto = await api.session("otto")
    form = aiohttp.FormData()
    form.add_field("machine", MACHINE)
    form.add_field("priority", "3")
    form.add_field("file", b"%\nO3001\nG0 X10 Y10\nG1 X20 F3000\nM30\n%\n", filename="api-part.nc")
    async with otto.post("/api/jobs", data=form) as r:
        reply = await r.json()
    assert r.status == 201 and reply["ok"], reply
    job_id = reply["job_id"]

    async def delivered() -> dict[str, Any] | None:
        async with otto.get(f"/api/jobs/{job_id}") as r:
            record: dict[str, Any] = await r.json()
        return record if record["state"] == "DELIVERED" else None

    record = await wait_until(delivered, timeout=30, message="the job to be delivered")
    assert record["user"] == "otto" and record["origin"].startswith("http ") and record["priority"] == 3
    assert [t["state"] for t in record["history"]][-1] == "DELIVERED"
    async with otto.get(f"/api/jobs?machine={MACHINE}&state=DELIVERED") as r:
        assert job_id in [j["id"] for j in (await r.json())["jobs"]]
    async with otto.post(f"/api/jobs/{job_id}/cancel") as r:
        refusal = await r.json()
    assert r.status == 409 and refusal["error"]["status"] == "BadInvalidState"
    assert "already DELIVERED" in refusal["error"]["reason"]


async def test_metrics_health_readiness_and_openapi(api: WebRig) -> None:
    session = await api.session(None)
    await wait_until(lambda: api.web.changes.get(MACHINE, 0) > 0, message="changes counted")
    # Under load a source can drop and come back (its watchdog): the page is read again, within a deadline,
    # until it is read at a moment the machine is connected; it must say so then.
    connected = f'cnc_gateway_machine_connected{{machine="{MACHINE}"}} 1.0'
    text = ""

    async def scrape() -> bool:
        nonlocal text
        async with session.get("/metrics") as r:
            assert r.status == 200 and r.headers["Content-Type"].startswith("text/plain")
            text = await r.text()
        return connected in text

    await wait_until(scrape, timeout=20, interval=0.2, message="/metrics to say the machine is connected")
    for line in (
        f'cnc_gateway_machine_connected{{machine="{MACHINE}"}} 1.0',
        f'cnc_gateway_machine_variables{{machine="{MACHINE}",quality="good"}}',
        f'cnc_gateway_machine_changes_total{{machine="{MACHINE}"}}',
        f'cnc_gateway_machine_reconnects_total{{machine="{MACHINE}"}}',
        f'cnc_gateway_machine_alarms_active{{machine="{MACHINE}"}}',
        f'cnc_gateway_machine_jobs{{machine="{MACHINE}",state="QUEUED"}}',
        'cnc_gateway_sink_backlog{sink="opcua"}',
        'cnc_gateway_sink_messages_total{sink="opcua"}',
        "process_resident_memory_bytes",
        "process_cpu_seconds_total",
        "cnc_gateway_ready 1.0",
    ):
        assert line in text, line
    async with session.get("/healthz") as r:
        assert r.status == 200
    async with session.get("/readyz") as r:
        assert r.status == 200 and (await r.json()) == {"ready": True, "waiting_for": []}

    doc = document()
    async with session.get("/api/openapi.json") as r:
        assert await r.json() == json.loads(json.dumps(doc))
    described = {(m.upper(), p) for p, ops in doc["paths"].items() for m in ops}
    registered = {
        (route.method, route.pattern.replace("{path*}", "{path}"))
        for route in api.web.router.routes
        if route.pattern.startswith("/api/") and route.pattern != "/api/openapi.json"
    }
    assert registered == described


async def test_login_lockout_and_session_cookie(api: WebRig) -> None:
    session = aiohttp.ClientSession(base_url=api.url, cookie_jar=aiohttp.CookieJar(unsafe=True))
    api.sessions.append(session)
    async with session.post(
        "/login", data={"username": "erik", "password": USERS["erik"][1]}, allow_redirects=False
    ) as r:
        cookie = r.headers["Set-Cookie"]
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie and "Secure" not in cookie
    api.web.sessions.users.limiter.failures = 3  # the lockout (gateway file: access.lockout), made quick
    for _ in range(3):
        async with session.post("/login", data={"username": "erik", "password": "guess"}) as r:
            assert r.status == 401
    async with session.post("/login", data={"username": "erik", "password": USERS["erik"][1]}) as r:
        assert r.status == 401  # locked out: even the right password is refused, unchecked
    api.web.sessions.users.limiter._records.clear()


async def test_tokens_cli_creates_lists_and_revokes(api: WebRig, capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        cli(["tokens", "create", "--user", "ada", "--label", "grafana", "--state-dir", str(api.state_dir)])
        == 0
    )
    token = capsys.readouterr().out.strip()
    session = await api.session(None)
    async with session.get("/api/gateway/config", headers={"Authorization": f"Bearer {token}"}) as r:
        config = await r.json()
    assert r.status == 200
    users = config["gateway"]["users"]
    assert users and all(u["password_hash"] == "********" for u in users)
    assert cli(["tokens", "list", "--state-dir", str(api.state_dir)]) == 0
    listed = capsys.readouterr().out
    assert "ada" in listed and "grafana" in listed and token not in listed
    stored = tokens_path(api.state_dir).read_text()
    assert token.split("_", 2)[2] not in stored  # only the hash is kept
    assert cli(["tokens", "revoke", token.split("_")[1], "--state-dir", str(api.state_dir)]) == 0
    async with session.get("/api/me", headers={"Authorization": f"Bearer {token}"}) as r:
        assert r.status == 401


async def test_a_taken_port_leaves_the_gateway_running_without_its_console(tmp_path: Path) -> None:
    blocker = await asyncio.start_server(lambda r, w: None, "127.0.0.1", 0)
    port = blocker.sockets[0].getsockname()[1]
    try:
        async with web_gateway(tmp_path, http={"host": "127.0.0.1", "port": port}) as rig:
            assert not rig.web.up
            assert "sink web" in rig.gateway.not_ready()
            assert rig.machine.nodes["Machine/State"].sample.good  # the other doors work
    finally:
        blocker.close()
        await blocker.wait_closed()


async def test_http_null_turns_the_console_off(tmp_path: Path) -> None:
    async with web_gateway(tmp_path, http=None) as rig:
        assert "web" not in [s.name for s in rig.gateway.sinks]


def _self_signed(folder: Path) -> None:
    """http-cert.pem and http-key.pem in `folder` (the state directory), as `openssl req -x509` makes them."""
    import datetime as dt

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "cnc-gateway")])
    now = dt.datetime.now(dt.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=1))
        .not_valid_after(now + dt.timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost")]), critical=False)
        .sign(key, hashes.SHA256())
    )
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "http-cert.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (folder / "http-key.pem").write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )


async def test_https_with_the_state_directorys_certificate_and_secure_cookies(tmp_path: Path) -> None:
    import ssl

    _self_signed(tmp_path / "state")
    from tests.waiting import free_port

    port = free_port()
    http = {"host": "127.0.0.1", "port": port, "tls": {}}
    async with web_gateway(tmp_path, http=http) as rig:
        context = ssl.create_default_context(cafile=str(tmp_path / "state" / "http-cert.pem"))
        context.check_hostname = False
        connector = aiohttp.TCPConnector(ssl=context)
        async with aiohttp.ClientSession(
            base_url=f"https://127.0.0.1:{port}",
            connector=connector,
            cookie_jar=aiohttp.CookieJar(unsafe=True),
        ) as session:
            async with session.post(
                "/login", data={"username": "otto", "password": USERS["otto"][1]}, allow_redirects=False
            ) as r:
                assert r.status == 303
                cookie = r.headers["Set-Cookie"]
            assert "Secure" in cookie and "HttpOnly" in cookie and "SameSite=Strict" in cookie
            async with session.get("/api/me") as r:
                assert (await r.json())["user"] == "otto"
        assert rig.web.url.startswith("https://")


async def test_a_missing_certificate_stops_the_start_with_what_to_do(tmp_path: Path) -> None:
    from gateway.errors import SinkError

    with pytest.raises(SinkError, match=r"web console TLS: .*http-cert\.pem does not exist; create it"):
        async with web_gateway(tmp_path, http={"host": "127.0.0.1", "port": 0, "tls": {}}):
            pass


def _junk(rng: Any, depth: int = 0) -> Any:
    """A JSON value of any shape, sometimes of the shape an operation wants."""
    choice = rng.randrange(9 if depth < 3 else 6)
    if choice == 0:
        return None
    if choice == 1:
        return rng.choice([True, False])
    if choice == 2:
        return rng.choice([0, -1, 1, 150, 151, 2**31, -(2**63), 10**30])
    if choice == 3:
        return rng.choice([0.5, -1e308, 1e-320, 3.0])
    if choice == 4:
        return rng.choice(["", "demo.nc", "x" * 300, "\u0000\u202e", "<script>", "../../etc/passwd"])
    if choice == 5:
        return rng.choice(["laser-sim", "J000001", "Feed/Override"])
    if choice == 6:
        return [_junk(rng, depth + 1) for _ in range(rng.randrange(4))]
    keys = ["value", "args", "deadline", "comment", "priority", "name", "x"]
    return {rng.choice(keys): _junk(rng, depth + 1) for _ in range(rng.randrange(4))}


SEGMENTS = ["laser-sim", "nope", "Commands", "Programs", "start", "List", "Feed/Override", "J000001", "1",
            "abc", "%2e%2e", "x" * 200, "Axes/X", "cert.der"]  # fmt: skip


async def test_random_requests_over_the_openapi_document_never_get_a_server_error(api: WebRig) -> None:
    """What schemathesis would do, without its dependencies: every operation of the document, with path
    parameters, queries and JSON bodies drawn at random (seeded, so a failure repeats)."""
    import random

    rng = random.Random(16)
    session = await api.session("erik")
    operations = [(m.upper(), p) for p, ops in document()["paths"].items() for m in ops]
    failures = []
    for i in range(400):
        method, template = operations[i % len(operations)]
        path = template
        while "{" in path:
            start = path.index("{")
            path = path[:start] + rng.choice(SEGMENTS) + path[path.index("}") + 1 :]
        if method == "POST" and path.endswith("/methods/Programs/Delete"):
            continue  # a real deletion of the simulator's program is not a refusal to test
        query = {
            rng.choice(["limit", "machine", "state", "view", "since", "path", "prefix"]): str(_junk(rng))
        }
        body = json.dumps(_junk(rng)).encode() if rng.random() < 0.8 else b"\xff\xfe{"
        async with session.request(
            method, path, params=query, data=body, headers={"Content-Type": "application/json"}
        ) as r:
            text = await r.text()
            if r.status >= 500 and r.status not in (502, 503, 504):
                failures.append(f"{method} {path} {query}: {r.status} {text[:200]}")
            elif r.status >= 400 and r.headers.get("Content-Type", "").startswith("application/json"):
                error = json.loads(text)["error"]
                if not (error["status"].startswith("Bad") and error["reason"]):
                    failures.append(f"{method} {path}: {text[:200]}")
    assert not failures, "\n".join(failures[:20])


async def test_a_drip_fed_job_shows_its_progress_on_the_machines_page_and_in_the_metrics(api: WebRig) -> None:
    """The serial DNC transport adds drip fields to a job's record; the console shows whatever is there."""
    from gateway.model.events import Event

    record = {"id": "J000777", "state": "SENDING", "filename": "long.nc", "progress": 12.5,
              "drip": {"block": 120, "lead": 8.5, "sent": 4096}}  # fmt: skip
    api.gateway.tree.events.publish(Event(MACHINE, "jobs/J000777", record, retain=True))
    session = await api.session(None)

    async def page() -> str | None:
        async with session.get("/") as r:
            text = await r.text()
        return text if "J000777 block 120, lead 8.5, sent 4096" in text else None

    await wait_until(page, message="the drip-feed on the machines page")
    async with session.get("/metrics") as r:
        text = await r.text()
    assert f'cnc_gateway_dnc_bytes_sent{{machine="{MACHINE}"}} 4096.0' in text
    assert f'cnc_gateway_dnc_lead_seconds{{machine="{MACHINE}"}} 8.5' in text
    api.gateway.tree.events.publish(
        Event(MACHINE, "jobs/J000777", {**record, "state": "DELIVERED"}, retain=True)
    )
    await wait_until(lambda: api.web.latest_jobs[MACHINE]["state"] == "DELIVERED", message="the job ended")
    async with session.get("/metrics") as r:
        assert "cnc_gateway_dnc_bytes_sent{" not in await r.text()
