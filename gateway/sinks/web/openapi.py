"""The OpenAPI 3.1 document of the REST API, served at /api/openapi.json. Pure data.

Written out by hand from one table (`OPERATIONS`), beside the handlers in api.py;
tests/integration/web checks that every route the console registers under /api is
described here and that every operation described answers.
"""

from __future__ import annotations

from typing import Any

from gateway import __version__

ERROR = {
    "type": "object",
    "required": ["error"],
    "properties": {
        "error": {
            "type": "object",
            "required": ["status", "reason"],
            "properties": {
                "status": {"type": "string", "description": "OPC UA status name, e.g. BadUserAccessDenied"},
                "reason": {"type": "string", "description": "What users read"},
            },
        }
    },
}

VARIABLE = {
    "type": "object",
    "required": ["path", "type", "value", "status", "quality", "source_ts"],
    "properties": {
        "path": {"type": "string"},
        "type": {"type": "string", "description": "Boolean, Int16, Double, String, Double[], …"},
        "unit": {"type": "string"},
        "description": {"type": "string"},
        "value": {},
        "status": {"type": "string", "description": "OPC UA status name: Good, BadNotConnected, …"},
        "quality": {"type": "string", "enum": ["good", "uncertain", "bad"]},
        "reason": {"type": "string"},
        "source_ts": {"type": "string", "format": "date-time"},
        "internal": {"type": "boolean"},
        "writable": {"type": "boolean"},
        "write_role": {"type": ["string", "null"]},
        "may_write": {"type": "boolean", "description": "Whether the caller's role may write it"},
        "range": {"type": "object", "properties": {"min": {"type": "number"}, "max": {"type": "number"}}},
    },
}

OBJ: dict[str, Any] = {"type": "object"}


def _param(name: str, where: str = "path", description: str = "", schema: Any = None) -> dict[str, Any]:
    return {
        "name": name,
        "in": where,
        "required": where == "path",
        "description": description,
        "schema": schema or {"type": "string"},
    }


MACHINE = _param("machine", description="Machine name, as in its mapping file")
PATH = _param("path", description="Variable path, slashes included (Axes/X/Position)")
JOB = _param("job", description="Job id, J000042")
LIMIT = _param("limit", "query", "How many, 1..1000", {"type": "integer", "minimum": 1, "maximum": 1000})


def _json_body(schema: Any, required: bool = True) -> dict[str, Any]:
    return {"required": required, "content": {"application/json": {"schema": schema}}}


# (method, path, summary, parameters, request body, success status, success schema, error statuses)
OPERATIONS: list[tuple[str, str, str, list[Any], Any, int, Any, list[int]]] = [
    (
        "get",
        "/api/machines",
        "Every machine: link state, quality counts, alarms, jobs",
        [],
        None,
        200,
        OBJ,
        [],
    ),
    (
        "get",
        "/api/machines/{machine}",
        "One machine with its variables and methods",
        [MACHINE],
        None,
        200,
        OBJ,
        [404],
    ),
    (
        "get",
        "/api/machines/{machine}/variables",
        "Many variables (?path=…&path=…), a subtree (?prefix=…) or all",
        [
            MACHINE,
            _param("path", "query", "A variable path; repeat for many"),
            _param("prefix", "query", "Every variable under this folder"),
        ],
        None,
        200,
        OBJ,
        [404],
    ),
    (
        "get",
        "/api/machines/{machine}/variables/{path}",
        "One variable",
        [MACHINE, PATH],
        None,
        200,
        VARIABLE,
        [404],
    ),
    (
        "put",
        "/api/machines/{machine}/variables/{path}",
        "Write a variable: the checks of every door (role, type, range), the controller's answer",
        [MACHINE, PATH],
        _json_body({"type": "object", "required": ["value"], "properties": {"value": {}}}),
        200,
        {"type": "object", "properties": {"ok": {"type": "boolean"}, "variable": VARIABLE}},
        [400, 403, 404, 405, 422, 502, 503],
    ),
    (
        "get",
        "/api/machines/{machine}/methods",
        "The machine's methods (Commands, Programs, DNC control)",
        [MACHINE],
        None,
        200,
        OBJ,
        [404],
    ),
    (
        "post",
        "/api/machines/{machine}/methods/{object}/{name}",
        "Call a method (a command, Programs.*, DNC pause/resume/restart): arguments by name or in order",
        [MACHINE, _param("object", description="Commands, Programs, …"), _param("name")],
        _json_body(
            {
                "type": "object",
                "properties": {
                    "args": {"oneOf": [{"type": "object"}, {"type": "array"}]},
                    "deadline": {
                        "type": "number",
                        "exclusiveMinimum": 0,
                        "maximum": 3600,
                        "description": "Seconds to wait (then 504 BadTimeout; the call goes on)",
                    },
                },
            },
            required=False,
        ),
        200,
        {
            "type": "object",
            "properties": {"ok": {"type": "boolean"}, "outputs": OBJ, "duration": {"type": "number"}},
        },
        [400, 403, 404, 409, 422, 429, 503, 504],
    ),
    (
        "get",
        "/api/alarms",
        "Active (retained) alarms, or the history",
        [
            _param("machine", "query"),
            _param(
                "view",
                "query",
                "active (default) or history",
                {"type": "string", "enum": ["active", "history"]},
            ),
            LIMIT,
        ],
        None,
        200,
        OBJ,
        [400, 404],
    ),
    (
        "post",
        "/api/alarms/{machine}/{occurrence}/acknowledge",
        "Acknowledge an alarm occurrence",
        [MACHINE, _param("occurrence", schema={"type": "integer"})],
        _json_body(
            {"type": "object", "properties": {"comment": {"type": "string", "maxLength": 1000}}}, False
        ),
        200,
        OBJ,
        [400, 403, 404, 409],
    ),
    (
        "post",
        "/api/alarms/{machine}/{occurrence}/confirm",
        "Confirm an acknowledged alarm occurrence",
        [MACHINE, _param("occurrence", schema={"type": "integer"})],
        _json_body(
            {"type": "object", "properties": {"comment": {"type": "string", "maxLength": 1000}}}, False
        ),
        200,
        OBJ,
        [400, 403, 404, 409],
    ),
    (
        "get",
        "/api/jobs",
        "Jobs, newest first",
        [
            _param("machine", "query"),
            _param("state", "query", "QUEUED, SENDING, …; repeat or comma-separate"),
            LIMIT,
        ],
        None,
        200,
        OBJ,
        [400, 422],
    ),
    (
        "post",
        "/api/jobs",
        (
            "Submit a program (multipart): the FTP inbox's validation and queue; 422 with the reason if "
            "rejected. The caller and its role (http.jobs_role) are checked before the body is read; at "
            "most http.max_uploads uploads at once (429)"
        ),
        [],
        {
            "required": True,
            "content": {
                "multipart/form-data": {
                    "schema": {
                        "type": "object",
                        "required": ["machine", "file"],
                        "properties": {
                            "machine": {"type": "string"},
                            "file": {"type": "string", "format": "binary"},
                            "name": {
                                "type": "string",
                                "description": "File name on the controller (default: the upload's)",
                            },
                            "priority": {"type": "integer", "minimum": -1000, "maximum": 1000},
                        },
                    }
                }
            },
        },
        201,
        {
            "type": "object",
            "properties": {
                "ok": {"type": "boolean"},
                "message": {"type": "string"},
                "job_id": {"type": ["string", "null"]},
            },
        },
        [400, 403, 404, 408, 413, 422, 429],
    ),
    (
        "get",
        "/api/jobs/{job}",
        "One job: its record (estimate, extents, drip-feed progress) and history",
        [JOB],
        None,
        200,
        OBJ,
        [404],
    ),
    (
        "post",
        "/api/jobs/{job}/retry",
        "Put a FAILED or CANCELLED job back in the queue",
        [JOB],
        None,
        200,
        OBJ,
        [403, 404, 409],
    ),
    (
        "post",
        "/api/jobs/{job}/cancel",
        "Take a waiting job out of the queue",
        [JOB],
        None,
        200,
        OBJ,
        [403, 404, 409],
    ),
    (
        "put",
        "/api/jobs/{job}/priority",
        "Change a waiting job's priority (higher goes first)",
        [JOB],
        _json_body(
            {
                "type": "object",
                "required": ["priority"],
                "properties": {"priority": {"type": "integer", "minimum": -1000, "maximum": 1000}},
            }
        ),
        200,
        OBJ,
        [400, 403, 404, 409],
    ),
    (
        "get",
        "/api/audit",
        "The audit trail, newest first: for http.audit_role (default: the admin role) only",
        [
            _param("machine", "query"),
            _param("user", "query"),
            _param("origin", "query", "opcua, mqtt, http, …"),
            _param("kind", "query", "write, call, acknowledge, confirm, job, trust, reject"),
            _param("since", "query", "90s, 15m, 2h, 7d, today, or ISO-8601"),
            LIMIT,
        ],
        None,
        200,
        OBJ,
        [400, 403],
    ),
    (
        "get",
        "/api/gateway",
        "Version, uptime, readiness and diagnostics (backlogs, drops)",
        [],
        None,
        200,
        OBJ,
        [],
    ),
    (
        "get",
        "/api/gateway/config",
        "The effective configuration, secrets masked (admin)",
        [],
        None,
        200,
        OBJ,
        [403],
    ),
    (
        "get",
        "/api/gateway/certificates",
        "OPC UA client certificates in trusted/ and rejected/",
        [],
        None,
        200,
        OBJ,
        [],
    ),
    (
        "post",
        "/api/gateway/certificates/{name}/trust",
        "Move a certificate from rejected/ to trusted/ (admin)",
        [_param("name", description="File name in rejected/")],
        None,
        200,
        OBJ,
        [403, 404],
    ),
    (
        "post",
        "/api/gateway/certificates/{name}/reject",
        "Move a certificate from trusted/ to rejected/ (admin)",
        [_param("name", description="File name in trusted/")],
        None,
        200,
        OBJ,
        [403, 404],
    ),
    ("get", "/api/me", "Who the gateway takes the caller for: user, role, and how", [], None, 200, OBJ, []),
]

ERROR_TEXT = {
    400: "Malformed request (BadDecodingError)",
    401: "Not logged in, or a bad token (BadIdentityTokenInvalid)",
    403: "The role may not (BadUserAccessDenied), or a missing CSRF token",
    404: "No such machine, variable, method, alarm or job",
    405: "Read-only variable (BadNotWritable)",
    408: "The request body stalled (BadTimeout, http.body_timeout)",
    409: "Not in a state that allows it (BadInvalidState, …)",
    413: "Too large (BadRequestTooLarge)",
    422: "Wrong type, out of range, wrong arguments, or a program validation rejected",
    429: "Too many at once: uploads (http.max_uploads), Programs.Backup calls (jobs.backups.per_hour)",
    502: "The controller refused (its own status)",
    503: "The controller is not connected (BadNotConnected)",
    504: "No answer within the deadline (BadTimeout)",
}


def document() -> dict[str, Any]:
    paths: dict[str, Any] = {}
    for method, path, summary, params, body, ok, schema, errors in OPERATIONS:
        op: dict[str, Any] = {
            "summary": summary,
            "operationId": f"{method}{path.replace('/', '_').replace('{', '').replace('}', '')}",
            "parameters": params,
            "responses": {
                str(ok): {"description": "OK", "content": {"application/json": {"schema": schema}}},
                **{
                    str(code): {
                        "description": ERROR_TEXT[code],
                        "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}},
                    }
                    for code in sorted({*errors, 401})
                },
            },
        }
        if body is not None:
            op["requestBody"] = body
        paths.setdefault(path, {})[method] = op
    return {
        "openapi": "3.1.0",
        "info": {
            "title": "cnc-gateway",
            "version": __version__,
            "description": "Machines, variables, commands, alarms, jobs and the audit trail of one gateway. "
            "Authenticate with `Authorization: Bearer <token>` (cnc-gateway tokens create --user NAME) or a "
            "console session (then unsafe methods need the X-CSRF-Token header). Every refusal is an HTTP "
            "status with the OPC UA status name and the reason.",
        },
        "servers": [{"url": "/"}],
        "components": {
            "schemas": {"Error": ERROR, "Variable": VARIABLE},
            "securitySchemes": {
                "token": {"type": "http", "scheme": "bearer"},
                "session": {"type": "apiKey", "in": "cookie", "name": "cnc_session"},
            },
        },
        "security": [{"token": []}, {"session": []}, {}],
        "paths": paths,
    }
