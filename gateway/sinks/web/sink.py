"""WebSink: the web console, the REST API and /metrics, as a sink of the gateway.

Like every sink it reads the tree and sends writes and calls back through the
tree's one path. It serves (server.py, aiohttp) on `http.host:http.port`:

    /                      pages (pages.py), made live by /api/live (live.py)
    /api/…                 the REST API (api.py), described at /api/openapi.json (openapi.py)
    /metrics               Prometheus (metrics.py)
    /healthz, /readyz      liveness; readiness (every sink up, every machine tried)
    /login, /logout        console sessions (sessions.py)
    /static/…              the console's own JavaScript and CSS: nothing from a CDN

A port that is taken is bound again with backoff (the gateway runs on without its
console meanwhile, and says so), as COPYDATA's tcp-server does.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Self
from urllib.parse import quote, urlsplit

from gateway import __version__
from gateway.auth.ratelimit import LoginLimiter
from gateway.auth.tokens import TokenStore, tokens_path
from gateway.errors import NotFound, RequestError, SinkError
from gateway.model.events import EventSubscription
from gateway.model.sample import quality_of
from gateway.model.tree import VariableTree
from gateway.reconnect import Backoff, OutageLog
from gateway.sinks.base import SinkHealth
from gateway.sinks.http_listener import Limits
from gateway.sinks.ports import Ports
from gateway.sinks.web.api import Api
from gateway.sinks.web.config import ConsoleConfig, HttpConfig
from gateway.sinks.web.http import (
    Admitted,
    HttpRequest,
    HttpResponse,
    json_response,
    redirect,
    refusal,
    refused,
    safe_path,
)
from gateway.sinks.web.live import Live
from gateway.sinks.web.metrics import CONTENT_TYPE, MachineFigures, Metrics, Scrape
from gateway.sinks.web.openapi import document
from gateway.sinks.web.pages import Pages, drip_of
from gateway.sinks.web.routes import Route, Router
from gateway.sinks.web.server import HttpServer, LiveSocket
from gateway.sinks.web.sessions import Caller, LoginRequired, Sessions
from gateway.tls import server_context

log = logging.getLogger("gateway.web")

STATIC = Path(__file__).with_name("static")
STATIC_TYPES = {
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".png": "image/png",
}
LIVE_PATH = "/api/live"


class WebSink:
    name = "web"

    def __init__(
        self,
        tree: VariableTree,
        config: ConsoleConfig,
        http: HttpConfig,
        ports: Ports,
        *,
        logins: LoginLimiter | None = None,  # the gateway's shared lockout (gateway/auth/lockout.py)
    ) -> None:
        self.tree = tree
        self.config = config
        self.http = http
        self.ports = ports
        self.started = time.monotonic()
        self.sessions = Sessions(
            config.gateway.user_directory(logins),
            TokenStore(tokens_path(config.state_dir)),
            idle=http.session_idle,
        )
        self.latest_jobs: dict[str, Mapping[str, Any]] = {}  # machine -> latest job record (for drip-feed)
        self.api = Api(tree, config, http, ports, started=self.started)
        self.pages = Pages(tree, self.api, self.latest_jobs)
        self.live = Live(tree)
        self.metrics = Metrics()
        self.router = Router()
        self.api.register(self.router)
        self.pages.register(self.router)
        r = self.router
        r.add("GET", "/healthz", self._healthz, public=True)
        r.add("GET", "/readyz", self._readyz, public=True)
        r.add("GET", "/metrics", self._metrics, public=True)
        r.add("GET", "/api/openapi.json", self._openapi, public=True)
        r.add("GET", "/static/{name}", self._static, public=True)
        r.add("GET", "/favicon.ico", self._no_icon, public=True)
        r.add("GET", "/login", self._login_page, public=True)
        r.add("POST", "/login", self._login, public=True)
        r.add("POST", "/logout", self._logout)
        tls = (
            server_context(config.state_dir, http.tls.cert, http.tls.key, "web console") if http.tls else None
        )
        jobs = ports.jobs
        self.server = HttpServer(
            admit=self.admit,
            socket_handler=self._socket,
            socket_path=LIVE_PATH,
            upload_dir=jobs.staging_file if jobs is not None else self._no_uploads,
            max_body=http.max_body,
            max_upload=jobs.max_upload if jobs is not None else http.max_body,
            max_uploads=http.max_uploads,
            body_timeout=http.body_timeout,
            limits=Limits.of(http.connections),
            tls=tls,
        )
        self.listening = False
        self._events: EventSubscription | None = None
        self._static_cache: dict[str, bytes] = {}
        self._bind_error = ""

    def _no_uploads(self) -> Path:
        return self.config.state_dir / "web-uploads" / f"{time.monotonic_ns()}"

    @property
    def up(self) -> bool:
        return self.listening

    @property
    def changes(self) -> dict[str, int]:
        """Value changes per machine since start (`Machine.changes`; for /metrics)."""
        return {name: machine.changes for name, machine in self.tree.machines.items()}

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.http.host in ("0.0.0.0", "::", "") else self.http.host
        return f"{'https' if self.http.tls else 'http'}://{host}:{self.server.port or self.http.port}/"

    async def __aenter__(self) -> Self:
        self._events = self.tree.events.subscribe("web")
        try:
            await self.server.start(self.http.host, self.http.port)
            self.listening = True
            self._report()
        except SinkError as exc:  # retried by run(): a taken port must not stop the other doors
            self._bind_error = str(exc)
        return self

    def _report(self) -> None:
        users = self.sessions.users
        anon = users.anonymous_role if users.anonymous_allowed else "refused (log in)"
        log.info(
            "web console, REST API and /metrics on %s (anonymous visitors: %s)%s",
            self.url,
            anon,
            "" if self.http.tls else "; plain HTTP: logins cross the network in clear (http.tls to encrypt)",
        )

    async def __aexit__(self, *exc_info: object) -> None:
        await self.server.stop()
        self.listening = False
        if self._events is not None:
            self._events.close()

    def health(self) -> SinkHealth:
        """Ready while the console's port is bound (a taken port is tried again with backoff)."""
        return SinkHealth(ready=self.listening, last_error=self._bind_error)

    async def run(self) -> None:
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self.live.run(), name="web:live")
            tg.create_task(self._follow_events(), name="web:events")
            if not self.listening:
                tg.create_task(self._bind(), name="web:bind")

    async def _bind(self) -> None:
        backoff = Backoff(1.0, 2.0, 30.0)
        outage = OutageLog(log, remind_every=300.0)
        outage.failed(
            "first", "web console: binding %s:%d again with backoff", self.http.host, self.http.port
        )
        while not self.listening:
            await asyncio.sleep(backoff.next())
            try:
                await self.server.start(self.http.host, self.http.port)
            except SinkError as exc:
                outage.failed(str(exc), "web console %s; retrying in the background", exc)
                continue
            self.listening = True
            outage.recovered("web console listening on %s:%d", self.http.host, self.http.port)
            self._report()

    async def _follow_events(self) -> None:
        sub = self._events
        assert sub is not None
        while True:
            for event in await sub.next_batch():
                if (
                    event.channel.startswith("jobs/J")
                    and isinstance(event.payload, Mapping)
                    and event.machine
                ):
                    self.latest_jobs[event.machine] = event.payload
                self.live.event(event)

    # --- requests --------------------------------------------------------------------------------

    def admit(self, req: HttpRequest) -> Admitted | HttpResponse:
        """Before the body is read: the route (404, 405), the caller (401, or the login page), and a route's
        own check (an upload's role and CSRF token: 403). Nothing a refused request sends is read."""
        found = self.router.match(req.method, req.path)
        if found is None:
            return refusal("BadNotFound", f"nothing at {req.path}", 404)
        if isinstance(found, list):
            response = refusal(
                "BadServiceUnsupported", f"{req.path} takes {', '.join(sorted(set(found)))}", 405
            )
            response.headers["Allow"] = ", ".join(sorted(set(found)))
            return response
        route, params = found
        req.params = params
        if route.public:
            return Admitted(functools.partial(self._public, route), route.files)
        try:
            caller = self.sessions.caller(req)
        except LoginRequired as exc:
            if req.path.startswith("/api/"):
                return refusal(exc.status, exc.reason, 401)
            return redirect(f"/login?next={_quote(req.path)}")
        try:
            if route.files:  # before an upload: its CSRF header (the form field is in the body) and role
                self.sessions.check_csrf(req, caller)
            if route.admit is not None:
                route.admit(req, caller)
        except RequestError as exc:
            return self._refused(req, exc)
        return Admitted(functools.partial(self._run, route, caller), route.files)

    async def _public(self, route: Route, req: HttpRequest) -> HttpResponse:
        try:
            return await route.handler(req)  # type: ignore[no-any-return]
        except RequestError as exc:
            return self._refused(req, exc)

    async def _run(self, route: Route, caller: Caller, req: HttpRequest) -> HttpResponse:
        try:
            self.sessions.check_csrf(req, caller)
            return await route.handler(req, caller)  # type: ignore[no-any-return]
        except RequestError as exc:
            return self._refused(req, exc)

    def _refused(self, req: HttpRequest, exc: RequestError) -> HttpResponse:
        if req.path.startswith("/api/") or req.method != "GET":
            return refused(exc)
        return self._error_page(req, exc)

    def _error_page(self, req: HttpRequest, exc: RequestError) -> HttpResponse:
        try:
            caller = self.sessions.caller(req)
        except LoginRequired:
            caller = Caller(None, None, "anonymous")
        response = self.pages.render(
            req, caller, "error.html", title="Refused", page="error", status=exc.status, reason=exc.reason
        )
        response.status = refused(exc).status
        return response

    async def _socket(self, req: HttpRequest, socket: LiveSocket) -> None:
        try:
            self.sessions.caller(req)
        except LoginRequired as exc:
            await socket.send(f'{{"error":{{"status":"{exc.status}","reason":"log in first"}}}}')
            return
        await self.live.serve(socket)

    # --- public routes ---------------------------------------------------------------------------

    async def _healthz(self, req: HttpRequest) -> HttpResponse:
        return json_response({"status": "ok", "version": __version__})

    async def _readyz(self, req: HttpRequest) -> HttpResponse:
        waiting = self.ports.gateway.not_ready()
        return json_response({"ready": not waiting, "waiting_for": waiting}, 503 if waiting else 200)

    async def _openapi(self, req: HttpRequest) -> HttpResponse:
        return json_response(document())

    async def _static(self, req: HttpRequest) -> HttpResponse:
        name = req.params["name"]
        kind = STATIC_TYPES.get(Path(name).suffix)
        if kind is None or "/" in name or name.startswith("."):
            raise NotFound(f"no file {name!r}")
        data = self._static_cache.get(name)
        if data is None:
            path = STATIC / name
            if not path.is_file():
                raise NotFound(f"no file {name!r}")
            data = self._static_cache[name] = await asyncio.to_thread(path.read_bytes)
        return HttpResponse(200, data, kind, {"Cache-Control": "no-cache"})

    async def _no_icon(self, req: HttpRequest) -> HttpResponse:
        return HttpResponse(204, b"", "image/x-icon", {"Cache-Control": "max-age=86400"})

    async def _metrics(self, req: HttpRequest) -> HttpResponse:
        scrape = Scrape(
            __version__, not self.ports.gateway.not_ready(), diagnostics=self.ports.gateway.diagnostics()
        )
        counts = await self.ports.jobs.job_counts() if self.ports.jobs is not None else {}
        alarms = self.ports.alarms
        for name, machine in self.tree.machines.items():
            quality = {"good": 0, "uncertain": 0, "bad": 0}
            for node in machine.mapped:
                quality[quality_of(node.sample.status).value] += 1
            figures = MachineFigures(
                connected=machine.status.is_connected,
                reconnects=machine.status.reconnects,
                changes=machine.changes,
                quality=quality,
                jobs=counts.get(name),
            )
            if alarms is not None and name in alarms.alarm_machines:
                figures.alarms_active = sum(1 for a in alarms.active_alarms(name) if a.get("active"))
            drip = drip_of(self.latest_jobs.get(name))
            if drip and self.latest_jobs[name].get("state") == "SENDING":
                figures.dnc_sent = _number(drip.get("sent"))
                figures.dnc_lead = _number(drip.get("lead"))
            scrape.machines[name] = figures
        return HttpResponse(200, self.metrics.render(scrape), CONTENT_TYPE)

    # --- logging in and out ----------------------------------------------------------------------

    async def _login_page(self, req: HttpRequest) -> HttpResponse:
        users = self.sessions.users
        return self.pages.login(
            req,
            Caller(None, None, "anonymous"),
            next_url=_next(req.arg("next")),
            anonymous_role=users.anonymous_role if users.anonymous_allowed else None,
        )

    async def _login(self, req: HttpRequest) -> HttpResponse:
        users = self.sessions.users
        next_url = _next(req.form.get("next"))
        origin = req.headers.get("origin")
        if origin and urlsplit(origin).netloc != req.headers.get("host", ""):
            return refusal("BadUserAccessDenied", "a login from another site's page is refused")
        session = await self.sessions.login(
            req.form.get("username", ""), req.form.get("password", ""), req.remote
        )
        if session is None:
            return self.pages.login(
                req,
                Caller(None, None, "anonymous"),
                next_url=next_url,
                status=401,
                message="Wrong user name or password (or too many failures from this address: wait a while).",
                anonymous_role=users.anonymous_role if users.anonymous_allowed else None,
            )
        response = redirect(next_url)
        response.cookies.append(self.sessions.cookie(session, secure=req.secure))
        return response

    async def _logout(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        self.sessions.logout(caller)
        response = redirect("/login")
        response.cookies.append(self.sessions.cookie(None, secure=req.secure))
        return response


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _next(value: str | None) -> str:
    """Where a login goes next: a clean path on this host, else "/" (see `safe_path`)."""
    return safe_path(value) or "/"


def _quote(path: str) -> str:
    return quote(path, safe="/")
