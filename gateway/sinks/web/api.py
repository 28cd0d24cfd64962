"""The REST API (JSON under /api; the document is /api/openapi.json, built by openapi.py).

Every write goes through `Machine.write_node` and every call through
`Machine.call_method` with the caller's WriteContext (origin `http`): the same
role, type and range checks, the same controller round trip and the same audit
entry as OPC UA, MQTT or COPYDATA. Alarm acknowledgements go to the alarm
managers, job operations to the job service, through the ports app.py hands in.
Requests refused before they reach the tree (a body that is not JSON, say) are
audited too, as the MQTT sink does. Every refusal is an HTTP status plus the
OPC UA status name and the reason.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Iterable, Mapping
from datetime import datetime
from typing import Any

from gateway import __version__
from gateway.codecs.since import parse_since
from gateway.errors import (
    AccessDenied,
    ConfirmTimeout,
    InvalidArgument,
    MalformedRequest,
    NotFound,
    RequestError,
    TooManyArguments,
    UnknownVariable,
)
from gateway.model.audit import AuditEntry, as_text
from gateway.model.methods import Method
from gateway.model.sample import quality_of, utcnow
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.sinks.ports import Ports
from gateway.sinks.web.config import ConsoleConfig, HttpConfig
from gateway.sinks.web.http import HttpRequest, HttpResponse, json_response, plain, refused
from gateway.sinks.web.routes import Router
from gateway.sinks.web.sessions import Caller

log = logging.getLogger("gateway.web")

GATEWAY = "(gateway)"  # the audit entries' machine for changes to the gateway itself (trust list)
MAX_LIMIT = 1000
MAX_DEADLINE = 3600.0


class MethodUnknown(NotFound):
    status = "BadMethodInvalid"


def variable_info(node: VariableNode, caller: Caller | None = None) -> dict[str, Any]:
    d = node.definition
    sample = node.sample
    machine = node.machine
    out: dict[str, Any] = {
        "path": node.path,
        "type": str(d.type),
        "unit": d.unit,
        "description": d.description,
        "value": plain(sample.value),
        "status": sample.status,
        "quality": quality_of(sample.status).value,
        "reason": sample.reason,
        "source_ts": plain(sample.source_ts),
        "internal": node.internal,
        "writable": d.writable and not node.internal,
        "range": None if d.range is None else {"min": d.range.min, "max": d.range.max},
        "write_role": None,
    }
    if out["writable"]:
        role = machine.write_role(node)
        out["write_role"] = role
        if caller is not None:
            out["may_write"] = machine.tree.access.allows(caller.role, role)
    return out


def method_info(method: Method, machine: Machine, caller: Caller | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {
        "object": method.object,
        "name": method.name,
        "description": method.description,
        "role": method.role,
        "inputs": [
            {"name": a.name, "type": str(a.type), "description": a.description} for a in method.inputs
        ],
        "outputs": [
            {"name": a.name, "type": str(a.type), "description": a.description} for a in method.outputs
        ],
    }
    if caller is not None:
        out["may_call"] = machine.tree.access.allows(caller.role, method.role)
    return out


def quality_counts(machine: Machine) -> dict[str, int]:
    counts = {"good": 0, "uncertain": 0, "bad": 0}
    for node in machine.mapped:
        counts[quality_of(node.sample.status).value] += 1
    return counts


def _limit(req: HttpRequest, default: int = 100) -> int:
    text = req.arg("limit")
    if text is None:
        return default
    if not text.isdigit() or not 1 <= int(text) <= MAX_LIMIT:
        raise MalformedRequest(f"limit must be a whole number from 1 to {MAX_LIMIT}")
    return int(text)


def _text_arg(req: HttpRequest, name: str) -> str | None:
    value = req.arg(name)
    if value is not None and (len(value) > 256 or not value.isprintable()):
        raise MalformedRequest(f"{name} must be printable text of at most 256 characters")
    return value or None


def _comment(body: Mapping[str, Any]) -> str:
    comment = body.get("comment", "")
    if not isinstance(comment, str) or len(comment) > 1000:
        raise MalformedRequest("comment must be text of at most 1000 characters")
    return comment


class Api:
    """The /api handlers; `register(router)` adds them."""

    def __init__(
        self, tree: VariableTree, config: ConsoleConfig, http: HttpConfig, ports: Ports, *, started: float
    ) -> None:
        self.tree = tree
        self.config = config
        self.http = http
        self.ports = ports
        self.started = started
        self.started_at = utcnow()
        self._calls: set[asyncio.Task[Any]] = set()  # calls that outlived their deadline: kept, and audited

    def register(self, r: Router) -> None:
        r.add("GET", "/api/machines", self.machines)
        r.add("GET", "/api/machines/{machine}", self.machine)
        r.add("GET", "/api/machines/{machine}/variables", self.variables)
        r.add("GET", "/api/machines/{machine}/variables/{path*}", self.variable)
        r.add("PUT", "/api/machines/{machine}/variables/{path*}", self.write)
        r.add("GET", "/api/machines/{machine}/methods", self.methods)
        r.add("POST", "/api/machines/{machine}/methods/{object}/{name}", self.call)
        r.add("GET", "/api/alarms", self.alarms)
        r.add("POST", "/api/alarms/{machine}/{occurrence}/acknowledge", self.acknowledge)
        r.add("POST", "/api/alarms/{machine}/{occurrence}/confirm", self.confirm)
        r.add("GET", "/api/jobs", self.jobs)
        r.add("POST", "/api/jobs", self.submit, files=1, admit=self.may_upload)
        r.add("GET", "/api/jobs/{job}", self.job)
        r.add("POST", "/api/jobs/{job}/retry", self.retry)
        r.add("POST", "/api/jobs/{job}/cancel", self.cancel)
        r.add("PUT", "/api/jobs/{job}/priority", self.priority)
        r.add("GET", "/api/audit", self.audit)
        r.add("GET", "/api/gateway", self.gateway)
        r.add("GET", "/api/gateway/config", self.effective_config)
        r.add("GET", "/api/gateway/certificates", self.certificates)
        r.add("POST", "/api/gateway/certificates/{name}/trust", self.trust)
        r.add("POST", "/api/gateway/certificates/{name}/reject", self.reject)
        r.add("GET", "/api/me", self.me)

    # --- machines and variables --------------------------------------------------------------------

    def _machine(self, name: str) -> Machine:
        machine = self.tree.machines.get(name)
        if machine is None:
            raise UnknownVariable(f"no machine {name!r}")
        return machine

    def summary(self, machine: Machine) -> dict[str, Any]:
        status = machine.status
        out: dict[str, Any] = {
            "name": machine.name,
            "description": machine.definition.description,
            "connected": status.is_connected,
            "state": status.state,
            "last_error": status.last_error,
            "reconnects": status.reconnects,
            "endpoint": machine.definition.endpoint,
            "variables": sum(1 for _ in machine.mapped),
            "quality": quality_counts(machine),
        }
        alarms = self.ports.alarms
        if alarms is not None and machine.name in alarms.alarm_machines:
            out["alarms_active"] = sum(1 for a in alarms.active_alarms(machine.name) if a.get("active"))
        queue = machine.nodes.get("Jobs/QueueLength")
        if queue is not None:
            out["jobs_waiting"] = queue.sample.value
        return out

    async def machines(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return json_response({"machines": [self.summary(m) for m in self.tree.machines.values()]})

    async def machine(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        machine = self._machine(req.params["machine"])
        out = self.summary(machine)
        out["variables"] = [variable_info(n, caller) for n in machine.nodes.values()]
        out["methods"] = [method_info(m, machine, caller) for m in machine.methods.values()]
        return json_response(out)

    async def variables(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        """Many (`?path=…&path=…`), a subtree (`?prefix=Axes/`), or all of them."""
        machine = self._machine(req.params["machine"])
        paths = req.args("path")
        prefix = req.arg("prefix")
        if paths:
            missing = [p for p in paths if p not in machine.nodes]
            if missing:
                raise UnknownVariable(f"{machine.name} has no variable {', '.join(map(repr, missing[:5]))}")
            nodes: Iterable[VariableNode] = [machine.nodes[p] for p in paths]
        elif prefix:
            stem = prefix.rstrip("/")
            nodes = [n for n in machine.nodes.values() if n.path == stem or n.path.startswith(stem + "/")]
            if not nodes:
                raise UnknownVariable(f"{machine.name} has no variable under {prefix!r}")
        else:
            nodes = machine.nodes.values()
        return json_response(
            {"machine": machine.name, "variables": [variable_info(n, caller) for n in nodes]}
        )

    async def variable(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        machine = self._machine(req.params["machine"])
        node = machine.nodes.get(req.params["path"])
        if node is None:
            raise UnknownVariable(f"{machine.name} has no variable {req.params['path']!r}")
        return json_response(variable_info(node, caller))

    async def write(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        """`{"value": …}`: the one write path; answered once the controller's value is back in the tree."""
        machine = self._machine(req.params["machine"])
        node = machine.nodes.get(req.params["path"])
        if node is None:
            raise UnknownVariable(f"{machine.name} has no variable {req.params['path']!r}")
        ctx = caller.context()
        try:
            body = req.json_object()
            if "value" not in body:
                raise MalformedRequest('expected {"value": …}')
        except RequestError as exc:  # refused before the tree: audited here, as MQTT does
            machine.audit_write(node, node.sample.value, None, ctx, exc)
            raise
        await machine.write_node(node, body["value"], ctx)
        return json_response({"ok": True, "variable": variable_info(node, caller)})

    # --- methods -----------------------------------------------------------------------------------

    async def methods(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        machine = self._machine(req.params["machine"])
        return json_response({"methods": [method_info(m, machine, caller) for m in machine.methods.values()]})

    async def call(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        """`{"args": {name: value} | [values], "deadline": seconds}`: outputs by name, and the time taken."""
        machine = self._machine(req.params["machine"])
        obj, name = req.params["object"], req.params["name"]
        method = machine.methods.get((obj, name))
        if method is None:
            raise MethodUnknown(f"{machine.name} has no method {obj}.{name}")
        ctx = caller.context()
        try:
            body = req.json_object() if req.body else {}
            args = _arguments(method, body.get("args", []))
            deadline = _deadline(body.get("deadline"))
        except RequestError as exc:
            machine.audit_call(method, [], ctx, exc)
            raise
        started = time.monotonic()
        task = asyncio.ensure_future(machine.call_method(method, args, ctx))
        task.set_name(f"web:call:{machine.name}/{obj}.{name}")
        try:
            outputs = await asyncio.wait_for(asyncio.shield(task), deadline)
        except TimeoutError:
            self._calls.add(task)
            task.add_done_callback(self._ended)
            raise ConfirmTimeout(
                f"{obj}.{name} did not answer within the deadline of {deadline:g} s; it goes on, and its "
                "outcome is in the audit trail"
            ) from None
        outputs = list(outputs)
        result = {a.name: plain(v) for a, v in zip(method.outputs, outputs, strict=False)}
        return json_response(
            {"ok": True, "outputs": result, "duration": round(time.monotonic() - started, 4)}
        )

    def _ended(self, task: asyncio.Task[Any]) -> None:
        self._calls.discard(task)
        if not task.cancelled():
            task.exception()  # retrieved: its refusal is in the audit trail already

    # --- alarms ------------------------------------------------------------------------------------

    async def alarms(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        port = self.ports.alarms
        machine = _text_arg(req, "machine")
        view = req.arg("view", "active")
        if view not in ("active", "history"):
            raise MalformedRequest("view is active or history")
        if machine is not None and (port is None or machine not in port.alarm_machines):
            raise UnknownVariable(f"{machine!r} has no alarms")
        if port is None:
            return json_response({view: []})
        if view == "active":
            return json_response({"active": port.active_alarms(machine)})
        return json_response({"history": await port.alarm_history(machine, _limit(req))})

    async def acknowledge(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return await self._alarm(req, caller, "acknowledge")

    async def confirm(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return await self._alarm(req, caller, "confirm")

    async def _alarm(self, req: HttpRequest, caller: Caller, kind: str) -> HttpResponse:
        port = self.ports.alarms
        name = req.params["machine"]
        if port is None or name not in port.alarm_machines:
            raise UnknownVariable(f"{name!r} has no alarms")
        machine = self._machine(name)
        ctx = caller.context()
        text = req.params["occurrence"]
        try:
            if not text.isdigit() or len(text) > 18:
                raise MalformedRequest(f"{text!r} is not an alarm occurrence number")
            comment = _comment(req.json_object() if req.body else {})
        except RequestError as exc:
            machine.audit(kind, f"Alarms/#{text[:20]}", ctx, error=exc)
            raise
        act = port.acknowledge_alarm if kind == "acknowledge" else port.confirm_alarm
        record = await act(name, int(text), ctx, comment)
        return json_response({"ok": True, "alarm": record})

    # --- jobs --------------------------------------------------------------------------------------

    def _jobs(self) -> Any:
        if self.ports.jobs is None:
            raise NotFound("no machine has a jobs section: there is no job queue")
        return self.ports.jobs

    def _may_operate_jobs(self, caller: Caller, what: str) -> None:
        access = self.tree.access
        access.require(caller.role, self.http.jobs_role, what)

    def may_upload(self, req: HttpRequest, caller: Caller) -> None:
        """Before an upload's body is read: a job queue, and a caller who may submit jobs. The machine is
        in the body, so a refusal is audited against the gateway."""
        self._jobs()
        try:
            self._may_operate_jobs(caller, "submit jobs")
        except AccessDenied as exc:
            self._audit_gateway("job", "Jobs/(upload)", caller, error=exc)
            raise

    async def jobs(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        if self.ports.jobs is None:
            return json_response({"jobs": []})
        machine = _text_arg(req, "machine")
        states = [s for value in req.args("state") for s in value.split(",") if s]
        records = await self.ports.jobs.list_jobs(machine=machine, states=states, limit=_limit(req, 50))
        return json_response({"jobs": records})

    async def job(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return json_response(await self._jobs().show_job(req.params["job"]))

    async def submit(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        """multipart/form-data: `machine`, `file`, optional `name` (on the controller) and `priority`."""
        jobs = self._jobs()
        machine_name = req.form.get("machine", "")
        # A machine of the fleet that another shard serves is not in this tree; on a shared (PostgreSQL)
        # queue it is among the job machines all the same: its job is validated and queued here.
        elsewhere = machine_name not in self.tree.machines and machine_name in jobs.job_machines
        machine = self._machine(machine_name) if machine_name and not elsewhere else None
        ctx = caller.context()
        target = f"Jobs/{(req.form.get('name') or (req.files[0].filename if req.files else ''))[:80]}"

        def audit(target: str, new: str, error: RequestError | None) -> None:
            if machine is not None:
                machine.audit("job", target, ctx, new=new, error=error)
            elif elsewhere:
                self._audit_gateway("job", target, caller, error=error, machine=machine_name, new=new)

        try:
            if not machine_name:
                raise MalformedRequest("multipart form field `machine` is missing")
            if machine_name not in jobs.job_machines:
                raise InvalidArgument(f"{machine_name} takes no jobs (its mapping has no jobs section)")
            if len(req.files) != 1:
                raise MalformedRequest("send exactly one file, in the multipart field `file`")
            upload = req.files[0]
            name = req.form.get("name") or upload.filename
            priority = _int(req.form.get("priority", "0"), "priority")
            self._may_operate_jobs(caller, f"submit jobs to {machine_name}")
        except RequestError as exc:
            audit(target, as_text(["submit"]), exc)
            raise
        reply = await jobs.submit_file(
            machine_name,
            name,
            upload.path,
            size=upload.size,
            sha256=upload.sha256,
            user=caller.name,
            origin=f"http {req.remote}",
            priority=priority,
        )
        body = {"ok": reply.ok, "message": reply.message, "job_id": reply.job_id}
        if reply.ok:
            audit(f"Jobs/{name[:80]}", as_text(["submit", reply.job_id]), None)
            return json_response(body, 201)
        refusal = InvalidArgument(reply.message)  # validation's verdict: the job is REJECTED, with its reason
        audit(f"Jobs/{name[:80]}", as_text(["submit", reply.job_id]), refusal)
        return json_response({**body, "error": {"status": refusal.status, "reason": reply.message}}, 422)

    async def retry(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return await self._operate(req, caller, "retry")

    async def cancel(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return await self._operate(req, caller, "cancel")

    async def priority(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return await self._operate(req, caller, "priority")

    async def _operate(self, req: HttpRequest, caller: Caller, action: str) -> HttpResponse:
        jobs = self._jobs()
        record = await jobs.show_job(req.params["job"])
        machine = self._machine(str(record["machine"]))
        ctx = caller.context()
        target = f"Jobs/{record['id']}"
        args: list[Any] = [action]
        try:
            self._may_operate_jobs(caller, f"{action} jobs of {machine.name}")
            if action == "priority":
                body = req.json_object()
                value = body.get("priority")
                if not isinstance(value, int) or isinstance(value, bool) or not -1000 <= value <= 1000:
                    raise MalformedRequest('expected {"priority": a whole number from -1000 to 1000}')
                args.append(value)
                record = await jobs.prioritize_job(record["id"], value)
            elif action == "retry":
                record = await jobs.retry_job(record["id"], caller.name)
            else:
                record = await jobs.cancel_job(record["id"], caller.name)
        except RequestError as exc:
            machine.audit("job", target, ctx, new=as_text(args), error=exc)
            raise
        machine.audit("job", target, ctx, new=as_text(args))
        return json_response({"ok": True, "job": record})

    # --- audit -------------------------------------------------------------------------------------

    def may_read_audit(self, caller: Caller) -> bool:
        return self._allowed(caller, self.http.auditor(list(self.config.gateway.roles)))

    def require_audit_reader(self, caller: Caller) -> None:
        """Every user's name and every change: for `http.audit_role` (the admin role by default) only."""
        self._require(caller, self.http.auditor(list(self.config.gateway.roles)), "read the audit trail")

    async def audit(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        self.require_audit_reader(caller)
        port = self.ports.audit
        since: datetime | None = None
        text = _text_arg(req, "since")
        if text:
            try:
                since = parse_since(text)
            except ValueError as exc:
                raise MalformedRequest(f"since: {exc}") from None
        if port is None:
            return json_response({"entries": []})
        entries = await port.query_audit(
            machine=_text_arg(req, "machine"),
            user=_text_arg(req, "user"),
            origin=_text_arg(req, "origin"),
            kind=_text_arg(req, "kind"),
            since=since,
            limit=_limit(req),
        )
        return json_response({"entries": [audit_row(e) for e in entries]})

    # --- the gateway -------------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        waiting = self.ports.gateway.not_ready()
        return {
            "version": __version__,
            "started": plain(self.started_at),
            "uptime": round(time.monotonic() - self.started, 1),
            "ready": not waiting,
            "waiting_for": waiting,
            "diagnostics": plain(self.ports.gateway.diagnostics()),
        }

    async def gateway(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return json_response(self.status())

    def is_admin(self, caller: Caller) -> bool:
        return self._allowed(caller, self.http.admin(list(self.config.gateway.roles)))

    def _admin(self, caller: Caller, what: str) -> None:
        self._require(caller, self.http.admin(list(self.config.gateway.roles)), what)

    def _allowed(self, caller: Caller, role: str) -> bool:
        access = self.tree.access
        return access.allows(caller.role, role) and (access.enabled or caller.user is not None)

    def _require(self, caller: Caller, role: str, what: str) -> None:
        """`role` or higher; with role checks off (access.enabled: false), a login at least."""
        self.tree.access.require(caller.role, role, what)
        if not self.tree.access.enabled and caller.user is None:
            raise AccessDenied(f"an anonymous caller may not {what} (access.enabled is false: log in)")

    def effective(self) -> dict[str, Any]:
        return self.config.effective()

    async def effective_config(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        self._admin(caller, "read the effective configuration")
        return json_response(self.effective())

    async def certificates(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        port = self.ports.trust
        return json_response({"certificates": port.certificates() if port is not None else []})

    async def trust(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return await self._certificate(req, caller, "trust")

    async def reject(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return await self._certificate(req, caller, "reject")

    async def _certificate(self, req: HttpRequest, caller: Caller, action: str) -> HttpResponse:
        port = self.ports.trust
        name = req.params["name"]
        started, at = time.monotonic(), utcnow()
        error: RequestError | None = None
        try:
            self._admin(caller, f"{action} OPC UA client certificates")
            if port is None:
                raise NotFound("the OPC UA server has no trust list")
            record = await asyncio.to_thread(port.trust if action == "trust" else port.reject, name)
        except RequestError as exc:
            error = exc
            raise
        finally:
            self._audit_gateway(action, f"pki/{name[:120]}", caller, error=error, at=at, started=started)
        return json_response({"ok": True, "certificate": record})

    def _audit_gateway(
        self,
        kind: str,
        target: str,
        caller: Caller,
        *,
        error: RequestError | None,
        at: datetime | None = None,
        started: float | None = None,
        machine: str = GATEWAY,
        new: str | None = None,
    ) -> None:
        """An audit entry for a change to the gateway itself, or one refused before it named a machine (or
        for a job sent to a machine of the fleet that another shard serves: `machine`)."""
        self.tree.audit(
            AuditEntry(
                at or utcnow(),
                kind,
                machine,
                target,
                "http",
                caller.user,
                caller.role,
                None,
                new,
                "Good" if error is None else error.status,
                "" if error is None else error.reason,
                0.0 if started is None else time.monotonic() - started,
            )
        )

    async def me(self, req: HttpRequest, caller: Caller) -> HttpResponse:
        return json_response({"user": caller.user, "role": caller.role, "via": caller.via})


def audit_row(e: AuditEntry) -> dict[str, Any]:
    return {
        "time": plain(e.time),
        "kind": e.kind,
        "machine": e.machine,
        "target": e.target,
        "origin": e.origin,
        "user": e.user,
        "role": e.role,
        "old": e.old,
        "new": e.new,
        "status": e.status,
        "reason": e.reason,
        "duration_ms": round(e.duration * 1000, 1),
    }


def _arguments(method: Method, given: Any) -> list[Any]:
    """Arguments by name (an object) or in order (a list), as the method's inputs list them."""
    if isinstance(given, list):
        return given
    if not isinstance(given, dict):
        raise MalformedRequest("args must be an object of arguments by name, or a list in order")
    names = [a.name for a in method.inputs]
    extra = [k for k in given if k not in names]
    if extra:
        raise TooManyArguments(f"{method.name} does not take {', '.join(map(repr, extra))}")
    out = []
    for name in names:
        if name not in given:
            break  # the method's own check names what is missing
        out.append(given[name])
    return out


def _deadline(value: Any) -> float | None:
    if value is None:
        return None
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or not 0 < value <= MAX_DEADLINE
    ):
        raise MalformedRequest(f"deadline must be a number of seconds, above 0 and at most {MAX_DEADLINE:g}")
    return float(value)


def _int(text: str, name: str) -> int:
    with contextlib.suppress(ValueError):
        value = int(text)
        if -1000 <= value <= 1000:
            return value
    raise MalformedRequest(f"{name} must be a whole number from -1000 to 1000")


__all__ = ["Api", "audit_row", "method_info", "refused", "variable_info"]
