"""COPYDATA settings in a mapping file: which variables the nesting software gets, and where to.

A variable opts in with `copydata: {id: 12}`. The machine's `copydata:` section
lists the targets, each with its transport (`tcp-client`, `tcp-server`, `udp`,
`win32`), its byte layout (id and length widths, text encoding), how it sends
(one frame per change or one per cycle, a rate limit, periodic snapshots) and
whether it accepts writes back.

The checks that need the whole file
(ids unique per machine, targets naming variables that exist, ids that fit the
id width) are in `copydata_issues`, which MachineMapping calls, so that each
error points at the exact key that is wrong.

`transport: win32` is accepted here on every system: a mapping file is
validated (`cnc-gateway check`, CI) wherever it is edited, and must give the
same answer there as on the Windows machine that runs it. Starting such a
target anywhere but on Windows is a start error (gateway.sinks.copydata).
"""

from __future__ import annotations

import codecs
import re
from collections.abc import Sequence
from typing import Any, Literal, Protocol

from pydantic import Field, ModelWrapValidatorHandler, ValidationError, field_validator, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from gateway.settings.base import Backoff, Strict

U32_MAX = 2**32 - 1
DEFAULT_TCP_PORT = 5020
DEFAULT_BIND = "0.0.0.0"
DEFAULT_UDP_SNAPSHOT = 5.0  # s: a UDP receiver may start at any time and has no connection to say so

Transport = Literal["tcp-client", "tcp-server", "udp", "win32"]
Width = Literal[1, 2, 4]

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,62}$")

# Which keys belong to which transport; the others are refused, so a typo shows.
_TRANSPORT_KEYS: dict[str, frozenset[str]] = {
    "tcp-client": frozenset({"host", "port", "timeout", "send_buffer", "backoff"}),
    "tcp-server": frozenset({"bind", "port", "max_clients", "send_buffer", "backoff"}),
    "udp": frozenset({"host", "port"}),
    "win32": frozenset({"window_class", "window_title", "timeout", "backoff"}),
}
_REQUIRED: dict[str, tuple[str, ...]] = {"tcp-client": ("host", "port"), "udp": ("host", "port")}
_SPECIFIC = frozenset().union(*_TRANSPORT_KEYS.values())


def _issue(loc: tuple[str | int, ...], message: str, value: Any = None) -> InitErrorDetails:
    return InitErrorDetails(type=PydanticCustomError("value_error", message), loc=loc, input=value)


def _raise(title: str, issues: list[InitErrorDetails]) -> None:
    if issues:
        raise ValidationError.from_exception_data(title, issues)


class VariableCopydata(Strict):
    """How one variable appears in COPYDATA frames: its id (the contract with the nesting software)."""

    id: int = Field(ge=0, le=U32_MAX, description="Variable id in the frames; unique within the machine")


def check_encoding(name: str) -> str:
    """A text encoding Python knows, stateless and without byte-order mark: the receiver reads N bytes."""
    try:
        codecs.lookup(name)
    except LookupError:
        raise ValueError(f"unknown text encoding {name!r}; e.g. utf-8, utf-16-le, gbk, cp1252") from None
    try:
        joined, apart = "ab".encode(name), "a".encode(name) + "b".encode(name)
        b"".decode(name)
    except (LookupError, TypeError, ValueError):
        raise ValueError(f"{name!r} is not a text encoding: it cannot encode text item by item") from None
    if joined != apart:
        raise ValueError(
            f"{name!r} adds a byte-order mark (or other state) to every text; "
            "use a BOM-less form such as utf-8, utf-16-le or utf-32-le"
        )
    return name


class CopydataTarget(Strict):
    """One receiver of a machine's frames: a nesting package, or one of its instances."""

    name: str = Field(description="Target name, unique within the machine: logs, status and task names")
    transport: Transport = Field(
        description="tcp-client: connect to the nesting software; tcp-server: it connects to us; "
        "udp: one datagram per frame; win32: WM_COPYDATA window messages (Windows only)"
    )
    host: str | None = Field(default=None, description="tcp-client, udp: the receiver's address")
    port: int | None = Field(
        default=None, ge=0, le=65535,
        description="tcp-client, udp: the receiver's port; "
        f"tcp-server: ours (default {DEFAULT_TCP_PORT}, 0: any free port)",
    )  # fmt: skip
    bind: str | None = Field(
        default=None, description=f"tcp-server: the address to listen on (default {DEFAULT_BIND})"
    )
    max_clients: int = Field(default=8, ge=1, le=1000, description="tcp-server: connections served at once")
    window_class: str | None = Field(default=None, description="win32: class name of the receiver's window")
    window_title: str | None = Field(default=None, description="win32: title of the receiver's window")
    timeout: float = Field(
        default=2.0, gt=0, le=60,
        description="Seconds: win32 SendMessageTimeout per frame; tcp-client connect timeout",
    )  # fmt: skip
    id_width: Width = Field(default=2, description="Bytes of each variable id field: 1, 2 or 4")
    len_width: Width = Field(default=2, description="Bytes of each data length field: 1, 2 or 4")
    encoding: str = Field(
        default="utf-8", description="Text encoding of String values: utf-8, utf-16-le, gbk, …"
    )
    max_cbdata: int = Field(
        default=1 << 20, ge=16, le=U32_MAX,
        description="Largest lpData sent (and accepted back); bigger snapshots are split over several frames",
    )  # fmt: skip
    mode: Literal["single", "batch"] = Field(
        default="batch",
        description="single: one dwData=1 frame per changed variable; batch: one dwData=2 frame per cycle",
    )
    max_rate: float | None = Field(
        default=50.0,
        gt=0,
        description="Most frames per second (changes in between keep the latest value); null: no limit",
    )
    snapshot_interval: float | None = Field(
        default=None, gt=0,
        description="Seconds between full snapshots (dwData=2, every variable); "
        f"one is always sent on (re)connect. udp: default {DEFAULT_UDP_SNAPSHOT:g}",
    )  # fmt: skip
    variables: list[str] | None = Field(
        default=None,
        min_length=1,
        description="Paths sent to this target; default: every variable with a copydata id",
    )
    connected_id: int | None = Field(
        default=None, ge=0, le=U32_MAX,
        description="Also send a Boolean under this id: true while the gateway reaches the controller",
    )  # fmt: skip
    accept_writes: bool = Field(
        default=False,
        description="Treat dwData=1/2 frames from the receiver as writes to readwrite variables "
        "(checked like any write)",
    )
    queue_limit: int = Field(
        default=1000, ge=1, le=1_000_000,
        description="Frames waiting per receiver; beyond it they are dropped and a fresh snapshot follows",
    )  # fmt: skip
    send_buffer: int | None = Field(
        default=None, ge=1024, le=64 * 1024 * 1024,
        description="TCP: socket send buffer in bytes (smaller keeps a slow receiver's backlog fresher)",
    )  # fmt: skip
    backoff: Backoff = Field(default_factory=Backoff)

    @field_validator("name")
    @classmethod
    def _name(cls, name: str) -> str:
        if not _NAME.match(name):
            raise ValueError(
                f"target name {name!r} must be 1-63 letters, digits, '_', '.' or '-', "
                "starting with a letter or digit"
            )
        return name

    @field_validator("encoding")
    @classmethod
    def _encoding(cls, name: str) -> str:
        return check_encoding(name)

    @field_validator("host", "bind", "window_class", "window_title")
    @classmethod
    def _not_empty(cls, value: str | None) -> str | None:
        if value is not None and not value.strip():
            raise ValueError("must not be empty")
        return value

    @model_validator(mode="wrap")
    @classmethod
    def _transport_keys(cls, data: Any, handler: ModelWrapValidatorHandler[CopydataTarget]) -> CopydataTarget:
        """Each transport's own keys: required ones present, other transports' ones absent.

        Checked on the raw keys, beside the field checks, so that all problems come out together.
        """
        issues = _key_issues(data) if isinstance(data, dict) else []
        try:
            target = handler(data)
        except ValidationError as exc:
            _raise("CopydataTarget", [_reissue(e) for e in exc.errors()] + issues)
            raise
        _raise("CopydataTarget", issues)
        return target

    # --- resolved settings ---------------------------------------------------------------------

    @property
    def listen_port(self) -> int:
        return DEFAULT_TCP_PORT if self.port is None else self.port

    @property
    def listen_address(self) -> str:
        return self.bind or DEFAULT_BIND

    @property
    def snapshot_every(self) -> float | None:
        if self.snapshot_interval is None and self.transport == "udp":
            return DEFAULT_UDP_SNAPSHOT
        return self.snapshot_interval

    def describe(self) -> str:
        """Where this target sends, for logs and status: `tcp-server 0.0.0.0:5020`."""
        if self.transport == "tcp-server":
            return f"tcp-server {self.listen_address}:{self.listen_port}"
        if self.transport == "win32":
            parts = [
                f"class {self.window_class!r}" if self.window_class else "",
                f"title {self.window_title!r}" if self.window_title else "",
            ]
            return "win32 window " + " ".join(p for p in parts if p)
        return f"{self.transport} {self.host}:{self.port}"


def _key_issues(data: dict[str, Any]) -> list[InitErrorDetails]:
    transport = data.get("transport")
    if transport not in _TRANSPORT_KEYS:
        return []  # the field check says what is wrong with it
    allowed = _TRANSPORT_KEYS[transport]
    issues = []
    for key in sorted(k for k in data if k in _SPECIFIC and k not in allowed):
        issues.append(_issue((key,), f"{key} is not used by transport {transport}", data[key]))
    for key in _REQUIRED.get(transport, ()):
        if data.get(key) is None:
            issues.append(_issue((key,), f"transport {transport} needs {key}"))
    if transport in ("tcp-client", "udp") and data.get("port") == 0:
        issues.append(_issue(("port",), "port 0 (any free port) is only meaningful for tcp-server", 0))
    if transport == "win32" and data.get("window_class") is None and data.get("window_title") is None:
        issues.append(
            _issue(("window_class",), "transport win32 needs window_class or window_title (or both)")
        )
    return issues


def _reissue(err: Any) -> InitErrorDetails:
    """A pydantic error as raised again beside ours (ValueError contexts become plain messages)."""
    if err["type"] in ("value_error", "assertion_error"):
        message = str(err["msg"]).removeprefix("Value error, ").removeprefix("Assertion failed, ")
        return _issue(tuple(err["loc"]), message, err.get("input"))
    details = InitErrorDetails(type=err["type"], loc=tuple(err["loc"]), input=err.get("input"))
    if "ctx" in err:
        details["ctx"] = err["ctx"]
    return details


class MachineCopydata(Strict):
    """The machine's COPYDATA targets: where its frames go."""

    targets: list[CopydataTarget] = Field(min_length=1, description="Receivers of this machine's frames")

    @field_validator("targets")
    @classmethod
    def _unique_names(cls, targets: list[CopydataTarget]) -> list[CopydataTarget]:
        first: dict[str, int] = {}
        issues = []
        for index, target in enumerate(targets):
            if target.name in first:
                issues.append(
                    _issue(
                        (index, "name"),
                        f"target name {target.name!r} is already used by targets[{first[target.name]}]",
                        target.name,
                    )
                )
            else:
                first[target.name] = index
        _raise("MachineCopydata", issues)
        return targets


# --- whole-file checks -------------------------------------------------------------------------


class _Var:
    """What the cross checks need of a variable (VariableSpec lives in mapping.py)."""

    def __init__(self, index: int, path: str, copydata: VariableCopydata | None) -> None:
        self.index = index
        self.path = path
        self.copydata = copydata


def copydata_issues(variables: Sequence[Any], copydata: MachineCopydata | None) -> None:
    """Cross checks over the whole mapping; raises a ValidationError whose errors point at each key.

    `variables` are the mapping's VariableSpecs (anything with `.path` and `.copydata`).
    """
    specs = [_Var(i, v.path, v.copydata) for i, v in enumerate(variables)]
    issues: list[InitErrorDetails] = []
    by_id: dict[int, _Var] = {}
    for var in specs:
        if var.copydata is None:
            continue
        vid = var.copydata.id
        other = by_id.get(vid)
        if other is not None:
            issues.append(
                _issue(
                    ("variables", var.index, "copydata", "id"),
                    f"copydata id {vid} is already used by variables[{other.index}] ({other.path}); "
                    "ids are unique per machine",
                    vid,
                )
            )
        else:
            by_id[vid] = var
    if copydata is not None:
        by_path = {v.path: v for v in specs}
        for t, target in enumerate(copydata.targets):
            issues.extend(_target_issues(t, target, by_path, by_id, specs))
    _raise("MachineMapping", issues)


def _target_issues(
    t: int, target: CopydataTarget, by_path: dict[str, _Var], by_id: dict[int, _Var], specs: list[_Var]
) -> list[InitErrorDetails]:
    where = ("copydata", "targets", t)
    issues: list[InitErrorDetails] = []
    chosen: list[_Var] = []
    if target.variables is None:
        chosen = [v for v in specs if v.copydata is not None]
        if not chosen:
            message = (
                f"target {target.name!r} has nothing to send: no variable has a copydata id "
                "(add copydata: {id: N} to the variables the nesting software needs)"
            )
            issues.append(_issue(where, message))
    else:
        seen: set[str] = set()
        for j, path in enumerate(target.variables):
            loc = (*where, "variables", j)
            var = by_path.get(path)
            if path in seen:
                issues.append(_issue(loc, f"{path!r} is listed twice", path))
            elif var is None:
                issues.append(_issue(loc, f"{path!r} is not a variable of this mapping", path))
            elif var.copydata is None:
                issues.append(_issue(loc, f"{path} has no copydata id (add copydata: {{id: N}} to it)", path))
            else:
                chosen.append(var)
            seen.add(path)
    max_id = (1 << (8 * target.id_width)) - 1
    too_wide = [v for v in chosen if v.copydata is not None and v.copydata.id > max_id]
    if too_wide:
        listed = ", ".join(f"{v.copydata.id} ({v.path})" for v in too_wide[:5] if v.copydata is not None)
        issues.append(
            _issue(
                (*where, "id_width"),
                f"copydata ids {listed} do not fit a {target.id_width}-byte id field (max {max_id})",
                target.id_width,
            )
        )
    cid = target.connected_id
    if cid is not None:
        if cid > max_id:
            issues.append(
                _issue(
                    (*where, "connected_id"),
                    f"{cid} does not fit a {target.id_width}-byte id field (max {max_id})",
                    cid,
                )
            )
        owner = by_id.get(cid)
        if owner is not None:
            issues.append(
                _issue((*where, "connected_id"), f"{cid} is already the copydata id of {owner.path}", cid)
            )
    return issues


class CopydataVariableEntry(Protocol):
    """What the COPYDATA sink reads of a variable's mapping entry."""

    @property
    def path(self) -> str: ...

    @property
    def copydata(self) -> VariableCopydata | None: ...


class CopydataMachineEntry(Protocol):
    """What the COPYDATA sink reads of a machine's mapping file (gateway/config/mapping.py
    `MachineMapping` fits it)."""

    @property
    def copydata(self) -> MachineCopydata | None: ...

    @property
    def variables(self) -> Sequence[CopydataVariableEntry]: ...
