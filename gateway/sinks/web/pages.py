"""The console's pages: server-rendered HTML (templates/), made live by static/console.js.

Each page is rendered from the tree and the ports at request time; values then
arrive over the live socket (live.py), so a page never has to be reloaded to stay
current. What a user may do is decided here only to show or hide inputs and
buttons: the requests they send are checked again, by the one write path, the
alarm managers and the API's role checks.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from datetime import datetime
from typing import Any
from urllib.parse import quote

from gateway import __version__
from gateway.codecs.since import parse_since
from gateway.model.tree import Machine, VariableTree
from gateway.sinks.web.api import Api, audit_row, method_info, quality_counts, variable_info
from gateway.sinks.web.http import HttpRequest, HttpResponse, html_response, plain
from gateway.sinks.web.routes import Router
from gateway.sinks.web.sessions import Caller
from gateway.sinks.web.templates import Templates

JOB_STATES = ("RECEIVED", "VALIDATED", "QUEUED", "SENDING", "DELIVERED", "REJECTED", "FAILED", "CANCELLED")
ORIGINS = ("opcua", "mqtt", "copydata", "http", "jobs", "cli", "demo")
KINDS = ("write", "call", "acknowledge", "confirm", "job", "trust", "reject")
DASH = "\u2013"  # what an empty cell shows
DRIP_KEYS = ("block", "lead", "sent", "lines", "paused", "restart_block")

# Where a machine's own state, program and block usually are: the last segments of a mapped path.
STATE_NAMES = ("statetext", "state", "mode")
PROGRAM_NAMES = ("program/name", "programname", "program")
BLOCK_NAMES = ("program/block", "block", "blocknumber", "line")


def when(value: Any) -> str:
    """A time as the pages show it: UTC, to the second."""
    if value is None or value == "":
        return DASH
    if isinstance(value, datetime):
        value = plain(value)
    text = str(value).replace("T", " ")
    return text[:19] + ("Z" if text.endswith(("Z", "+00:00")) else "")


def drip_of(record: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """The drip-feed fields of a job record, when it has any (the serial DNC transport adds them)."""
    if not record:
        return None
    drip = record.get("drip")
    source: Mapping[str, Any] = drip if isinstance(drip, Mapping) else record
    found = {k: source[k] for k in DRIP_KEYS if k in source and source[k] is not None}
    return found or None


def _find(machine: Machine, names: tuple[str, ...]) -> str | None:
    paths = [n.path for n in machine.mapped]
    for name in names:
        for path in paths:
            if path.lower() == name or path.lower().endswith("/" + name):
                return path
    return None


def job_view(record: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(record)
    estimate = record.get("estimate") or {}
    seconds = estimate.get("seconds") if isinstance(estimate, Mapping) else None
    out["estimate_text"] = f"{seconds:.0f} s" if isinstance(seconds, (int, float)) else DASH
    extents = estimate.get("extents") if isinstance(estimate, Mapping) else None
    out["extents_text"] = _extents(extents) if isinstance(extents, Mapping) else DASH
    if isinstance(estimate, Mapping) and isinstance(estimate.get("cut_mm"), (int, float)):
        out["estimate_text"] += f", {estimate['cut_mm']:.0f} mm cut"
    progress = record.get("progress")
    drip = drip_of(record)
    out["drip"] = drip
    text = f"{progress:.0f} %" if isinstance(progress, (int, float)) else ""
    if drip:
        text += " · " + ", ".join(f"{k} {v}" for k, v in drip.items())
    out["progress_text"] = text or ("100 %" if record.get("state") == "DELIVERED" else DASH)
    out.setdefault("priority", 0)
    return out


def _extents(extents: Mapping[str, Any]) -> str:
    """The validator's extents (min_x, max_x, …) as `X 10..330 Y 5..150 Z 0..10`."""
    parts = []
    for axis in ("x", "y", "z"):
        low, high = extents.get(f"min_{axis}"), extents.get(f"max_{axis}")
        if isinstance(low, (int, float)) and isinstance(high, (int, float)):
            parts.append(f"{axis.upper()} {low:g}..{high:g}")
    return " ".join(parts) or DASH


def uptime(seconds: float) -> str:
    minutes, s = divmod(int(seconds), 60)
    hours, m = divmod(minutes, 60)
    days, h = divmod(hours, 24)
    return (f"{days} d " if days else "") + f"{h:02d}:{m:02d}:{s:02d}"


class Pages:
    def __init__(self, tree: VariableTree, api: Api, latest_jobs: Mapping[str, Mapping[str, Any]]) -> None:
        self.tree = tree
        self.api = api
        self.templates = Templates(filters={"when": when})
        self.latest_jobs = latest_jobs  # machine -> its latest job record seen on the event bus
        self._summary_paths: dict[
            str, tuple[str | None, str | None, str | None]
        ] = {}  # definitions are fixed

    def register(self, r: Router) -> None:
        r.add("GET", "/", self.machines)
        r.add("GET", "/machines/{machine}", self.machine)
        r.add("GET", "/alarms", self.alarms)
        r.add("GET", "/jobs", self.jobs)
        r.add("GET", "/jobs/{job}", self.job)
        r.add("GET", "/audit", self.audit)
        r.add("GET", "/gateway", self.gateway)

    def render(self, req: HttpRequest, caller: Caller, template: str, **context: Any) -> HttpResponse:
        context.setdefault("watch", None)
        here = req.path + (
            ("?" + "&".join(f"{k}={quote(v[-1])}" for k, v in req.query.items())) if req.query else ""
        )
        return html_response(
            self.templates.render(
                template,
                me=caller,
                csrf=caller.csrf,
                version=__version__,
                here=here,
                may_audit=self.api.may_read_audit(caller),
                **context,
            )
        )

    def login(
        self,
        req: HttpRequest,
        caller: Caller,
        *,
        message: str = "",
        next_url: str = "/",
        anonymous_role: str | None = None,
        status: int = 200,
    ) -> HttpResponse:
        response = self.render(
            req,
            caller,
            "login.html",
            title="Log in",
            page="login",
            message=message,
            next=next_url,
            anonymous_role=anonymous_role,
        )
        response.status = status
        return response

    # --- machines --------------------------------------------------------------------------------

    async def machines(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        alarms = self.api.ports.alarms
        diagnostics = self.api.ports.gateway.diagnostics()
        mqtt = diagnostics.get("sinks", {}).get("mqtt")
        mqtt_state = str(mqtt.get("state", "on")) if isinstance(mqtt, Mapping) else "off"
        rows = []
        paths: set[str] = {"Status/State", "Status/LastError", "Jobs/QueueLength", "Status/CopydataTargets"}
        for m in self.tree.machines.values():
            found = self._summary_paths.get(m.name)
            if found is None:
                found = self._summary_paths[m.name] = (
                    _find(m, STATE_NAMES),
                    _find(m, PROGRAM_NAMES),
                    _find(m, BLOCK_NAMES),
                )
            row: dict[str, Any] = {
                "name": m.name,
                "description": m.definition.description,
                "state_path": found[0],
                "program_path": found[1],
                "block_path": found[2],
                "alarms": None,
                "jobs": "Jobs/QueueLength" in m.nodes,
                "copydata": "Status/CopydataTargets" in m.nodes,
                "quality": quality_counts(m),
                "variables": sum(1 for _ in m.mapped),
                "drip": _drip_text(self.latest_jobs.get(m.name)),
            }
            if alarms is not None and m.name in alarms.alarm_machines:
                row["alarms"] = sum(1 for a in alarms.active_alarms(m.name) if a.get("active"))
            paths.update(p for p in (row["state_path"], row["program_path"], row["block_path"]) if p)
            rows.append(row)
        watch = {"watch": [{"machine": "*", "paths": sorted(paths)}], "events": True}
        return self.render(
            req,
            caller,
            "machines.html",
            title="Machines",
            page="machines",
            machines=rows,
            mqtt=mqtt_state,
            watch=watch,
        )

    async def machine(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        machine = self.api._machine(req.params["machine"])
        variables = []
        folders: tuple[str, ...] = ()
        for node in machine.nodes.values():
            parts = tuple(node.path.split("/"))
            info = variable_info(node, caller)
            common = 0
            while common < min(len(folders), len(parts) - 1) and folders[common] == parts[common]:
                common += 1
            for depth in range(common, len(parts) - 1):  # a row for each folder that starts here
                variables.append({"folder": parts[depth], "depth": depth, "header": True})
            folders = parts[:-1]
            info.update(name=parts[-1], depth=len(parts) - 1, header=False)
            variables.append(info)
        methods = [method_info(m, machine, caller) for m in machine.methods.values()]
        alarms = self.api.ports.alarms
        active = (
            alarms.active_alarms(machine.name) if alarms and machine.name in alarms.alarm_machines else None
        )
        jobs = self.api.ports.jobs
        has_jobs = jobs is not None and machine.name in jobs.job_machines
        watch = {"watch": [{"machine": machine.name, "paths": None}], "events": True}
        return self.render(
            req,
            caller,
            "machine.html",
            title=machine.name,
            page="machine",
            m=self.api.summary(machine) | {"endpoint": machine.definition.endpoint},
            variables=variables,
            methods=methods,
            alarms=active,
            jobs=[] if has_jobs else None,
            show_machine=False,
            may_ack=self._may_ack(caller),
            watch=watch,
        )

    def _may_ack(self, caller: Caller) -> Any:
        alarms = self.api.ports.alarms

        def may(machine: str) -> bool:
            return alarms is not None and self.tree.access.allows(
                caller.role, alarms.acknowledge_role(machine)
            )

        return may

    # --- alarms, jobs, audit, gateway ------------------------------------------------------------

    async def alarms(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        port = self.api.ports.alarms
        active = port.active_alarms() if port is not None else []
        recent = await port.alarm_history(None, 100) if port is not None else []
        return self.render(
            req,
            caller,
            "alarms.html",
            title="Alarms",
            page="alarms",
            active=active,
            recent=recent,
            may_ack=self._may_ack(caller),
            watch={"events": True},
        )

    async def jobs(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        port = self.api.ports.jobs
        machine = req.arg("machine") or None
        state = req.arg("state") or None
        if state is not None and state not in JOB_STATES:
            state = None
        records = (
            await port.list_jobs(machine=machine, states=[state] if state else [], limit=100)
            if port is not None
            else []
        )
        may_submit = self.tree.access.allows(caller.role, self.api.http.jobs_role)
        return self.render(
            req,
            caller,
            "jobs.html",
            title="Jobs",
            page="jobs",
            jobs=[job_view(j) for j in records],
            machines=sorted(port.job_machines) if port is not None else [],
            machine=machine,
            state=state,
            states=JOB_STATES,
            may_submit=may_submit,
            watch={"events": True},
        )

    async def job(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        record = await self.api._jobs().show_job(req.params["job"])
        return self.render(req, caller, "job.html", title=str(record["id"]), page="jobs", j=job_view(record))

    async def audit(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        self.api.require_audit_reader(caller)
        f = {k: (req.arg(k) or None) for k in ("machine", "user", "origin", "kind", "since")}
        message = ""
        entries: list[dict[str, Any]] = []
        port = self.api.ports.audit
        since = None
        if f["since"]:
            try:
                since = parse_since(f["since"])
            except ValueError as exc:
                message = str(exc)
        if port is not None and not message:
            found = await port.query_audit(
                machine=f["machine"],
                user=f["user"],
                origin=f["origin"],
                kind=f["kind"],
                since=since,
                limit=200,
            )
            entries = [audit_row(e) for e in found]
        return self.render(
            req,
            caller,
            "audit.html",
            title="Audit",
            page="audit",
            f=f,
            entries=entries,
            message=message,
            origins=ORIGINS,
            kinds=KINDS,
        )

    async def gateway(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        status = self.api.status()
        admin = self.api.is_admin(caller)
        trust = self.api.ports.trust
        return self.render(
            req,
            caller,
            "gateway.html",
            title="Gateway",
            page="gateway",
            status=status,
            uptime=uptime(time.monotonic() - self.api.started),
            admin=admin,
            certificates=trust.certificates() if trust is not None else [],
            config=self.api.effective() if admin else {},
        )


def _drip_text(record: Mapping[str, Any] | None) -> str:
    if not record or record.get("state") != "SENDING":
        return ""
    drip = drip_of(record)
    if not drip:
        return ""
    return f"{record.get('id', '')} " + ", ".join(f"{k} {v}" for k, v in drip.items())
