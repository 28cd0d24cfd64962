"""Load YAML configuration with line numbers, and report every error at once.

PyYAML forgets where values came from once it builds Python objects, so this
module composes the node graph itself and records the line of every key and list
item. Pydantic's error locations are then mapped back to `file:line: key`.
It also rejects duplicate keys (PyYAML silently keeps the last one) and expands
`${NAME}` / `${NAME:-default}` references from the environment, so that secrets
stay out of files.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from gateway.alarms.config import SOURCE_TAGS
from gateway.auth.known_passwords import is_known, known_passwords_of
from gateway.config.gateway import GatewayConfig
from gateway.config.jobs import JobsConfig
from gateway.config.mapping import MachineMapping, tree_conflicts
from gateway.errors import AddressError, ConfigError, ConfigIssue
from gateway.model.definitions import MachineDefinition
from gateway.settings.access import DEFAULT_ROLES, REFUSE, ROLE_RE, unknown_role
from gateway.settings.masking import masked
from gateway.shards.static import select
from gateway.sources import registry
from gateway.transports import registry as transports

Loc = tuple[str | int, ...]
M = TypeVar("M", bound=BaseModel)

ENV_RE = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")


@dataclass
class Located:
    """Plain Python data from a YAML document, with the line of every location in it."""

    file: str
    data: Any
    lines: dict[Loc, int] = field(default_factory=dict)

    def line(self, loc: Loc) -> int | None:
        """The line of `loc`, or of its nearest ancestor that exists in the file."""
        for cut in range(len(loc), -1, -1):
            line = self.lines.get(tuple(loc[:cut]))
            if line is not None:
                return line
        return None


def format_loc(loc: Loc) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def read_yaml(path: Path, environ: Mapping[str, str] | None = None) -> Located:
    """Parse one YAML file into data plus line numbers. Raises ConfigError on any problem."""
    file = str(path)
    env = os.environ if environ is None else environ
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError([ConfigIssue(file, None, "", f"cannot read file: {exc.strerror or exc}")]) from None
    except UnicodeDecodeError as exc:
        raise ConfigError([ConfigIssue(file, None, "", f"not UTF-8 text: {exc.reason}")]) from None
    try:
        node = _compose(text)
    except yaml.YAMLError as exc:
        raise ConfigError([_yaml_issue(file, exc)]) from None
    if node is None:
        raise ConfigError([ConfigIssue(file, 1, "", "the file is empty")])
    builder = _Builder(Located(file, None), env)
    builder.located.data = builder.build(node, ())
    if builder.issues:
        raise ConfigError(builder.issues)
    return builder.located


# libyaml's parser, when PyYAML was built with it: a tenth of the pure-Python parser's time (20 mapping
# files of 500 variables took 4 s of the gateway's start-up). Both compose the same nodes with the same marks.
_FAST_LOADER: Any = getattr(yaml, "CSafeLoader", None)


def _compose(text: str) -> yaml.Node | None:
    """The document's node graph. A document libyaml refuses goes to PyYAML's own parser, whose error
    messages are the ones users see (and the corpus tests expect), and which accepts a few things
    libyaml does not."""
    if _FAST_LOADER is not None:
        try:
            return yaml.compose(text, Loader=_FAST_LOADER)
        except yaml.YAMLError:
            pass
    return yaml.compose(text, Loader=yaml.SafeLoader)


def _yaml_issue(file: str, exc: yaml.YAMLError) -> ConfigIssue:
    """Locate a syntax error where the user can fix it: where the broken construct began
    if the parser only noticed at the end of the file, else where it noticed."""
    problem_mark = getattr(exc, "problem_mark", None)
    context_mark = getattr(exc, "context_mark", None)
    problem = getattr(exc, "problem", None) or str(exc)
    context = getattr(exc, "context", None)
    mark = problem_mark
    if context_mark is not None and (problem_mark is None or "<stream end>" in problem):
        mark = context_mark
    message = f"invalid YAML: {problem}"
    if context and context_mark is not None:
        message += f" ({context} at line {context_mark.line + 1})"
    return ConfigIssue(file, mark.line + 1 if mark is not None else None, "", message)


class _Builder:
    """Turns a composed YAML node graph into plain data, recording lines as it goes."""

    def __init__(self, located: Located, env: Mapping[str, str]) -> None:
        self.located = located
        self.env = env
        self.issues: list[ConfigIssue] = []
        self.constructor = yaml.constructor.SafeConstructor()

    def build(self, node: yaml.Node, loc: Loc) -> Any:
        lines = self.located.lines
        lines.setdefault(loc, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            out: dict[str, Any] = {}
            for key_node, value_node in node.value:
                key = str(self.scalar(key_node))
                sub = (*loc, key)
                if key in out:
                    self.issues.append(
                        ConfigIssue(
                            self.located.file,
                            key_node.start_mark.line + 1,
                            format_loc(sub),
                            f"duplicate key (first at line {lines[sub]})",
                        )
                    )
                    continue
                lines[sub] = key_node.start_mark.line + 1
                out[key] = self.build(value_node, sub)
            return out
        if isinstance(node, yaml.SequenceNode):
            return [self.build(item, (*loc, i)) for i, item in enumerate(node.value)]
        value = self.scalar(node)
        if isinstance(value, str) and "${" in value:
            return self.expand_env(value, loc)
        return value

    def scalar(self, node: yaml.Node) -> Any:
        if not isinstance(node, yaml.ScalarNode):
            return str(node.value)
        return self.constructor.construct_object(node)

    def expand_env(self, value: str, loc: Loc) -> str:
        def repl(m: re.Match[str]) -> str:
            name, default = m.group(1), m.group(2)
            if name in self.env:
                return self.env[name]
            if default is not None:
                return default
            self.issues.append(
                ConfigIssue(
                    self.located.file,
                    self.located.lines.get(loc),
                    format_loc(loc),
                    f"environment variable {name} is not set (use ${{{name}:-default}} to give a default)",
                )
            )
            return ""

        return ENV_RE.sub(repl, value)


def validate(model: type[M], located: Located) -> M:
    """Validate located data against a model; every pydantic error becomes a located issue."""
    try:
        return model.model_validate(located.data)
    except ValidationError as exc:
        raise ConfigError(issues_from(exc, located)) from None


def issues_from(exc: ValidationError, located: Located) -> list[ConfigIssue]:
    issues = []
    for err in exc.errors(include_url=False):
        loc = tuple(err["loc"])
        # pydantic adds the tag of a function validator or a union member to the location
        loc = tuple(p for p in loc if not (isinstance(p, str) and ("[" in p or p.startswith("function-"))))
        loc = _untagged(loc)
        message = _message(err)
        issues.append(ConfigIssue(located.file, located.line(loc), format_loc(loc), message))
    return issues


def _untagged(loc: Loc) -> Loc:
    """Without the member names pydantic puts after a tagged union (`driver.opcua.endpoint`)."""
    for at, tags in (
        (("driver",), registry.types()),
        (("alarms", "source"), SOURCE_TAGS),
        (("jobs", "controller"), transports.types()),
    ):
        n = len(at)
        if len(loc) > n and loc[:n] == at and loc[n] in tags:
            return (*at, *loc[n + 1 :])
    return loc


def _message(err: Mapping[str, Any]) -> str:
    kind = err["type"]
    msg = str(err["msg"])
    msg = msg.removeprefix("Value error, ")
    if kind == "extra_forbidden":
        return "unknown key (check the spelling; see mappings/mapping.schema.json for the keys allowed)"
    if kind == "missing":
        return "required key is missing"
    got = err.get("input")
    if kind not in ("value_error", "assertion_error") and not isinstance(got, (dict, list)):
        msg = f"{msg} (got {got!r})"
    return msg


# --- whole configurations ------------------------------------------------------------------------


@dataclass(frozen=True)
class Config:
    """A validated gateway configuration: gateway-wide settings plus each machine's mapping."""

    gateway: GatewayConfig
    machines: tuple[MachineMapping, ...]
    base_dir: Path
    files: tuple[Path, ...] = ()
    # With `shard:`, the jobs sections of the fleet's machines that other shards serve: an inbox on a shared
    # (PostgreSQL) queue takes and validates their jobs too (gateway/jobs/service.py). Empty otherwise.
    jobs_elsewhere: Mapping[str, JobsConfig] = field(default_factory=dict)

    @property
    def state_dir(self) -> Path:
        return (self.base_dir / self.gateway.state_dir).resolve()

    @property
    def mappings(self) -> dict[str, MachineMapping]:
        """Each machine's mapping by machine name: what the components read beside the tree."""
        return {m.machine: m for m in self.machines}

    def effective(self) -> dict[str, Any]:
        """Every file's settings as JSON data, secrets masked (the console's Gateway page)."""
        return {
            "gateway": masked(self.gateway),
            "machines": {name: masked(mapping) for name, mapping in self.mappings.items()},
            "files": [str(f) for f in self.files],
        }

    def definitions(self) -> list[MachineDefinition]:
        """The machines as the variable tree knows them (`VariableTree(config.definitions())`)."""
        return [m.definition() for m in self.machines]


def load_mapping(
    path: Path, environ: Mapping[str, str] | None = None, roles: Sequence[str] | None = None
) -> MachineMapping:
    """One mapping file. `roles` are the gateway file's (default: viewer, operator, engineer, admin);
    every role the mapping names must be one of them."""
    return _read_mapping(path, environ, roles)[0]


def _read_mapping(
    path: Path, environ: Mapping[str, str] | None, roles: Sequence[str] | None
) -> tuple[MachineMapping, Located]:
    located = read_yaml(path, environ)
    if not isinstance(located.data, dict):
        raise ConfigError(
            [ConfigIssue(str(path), 1, "", "a mapping file must be a YAML mapping with a 'machine' key")]
        )
    issues: list[ConfigIssue] = []
    mapping: MachineMapping | None = None
    try:
        mapping = validate(MachineMapping, located)
    except ConfigError as exc:
        issues.extend(exc.issues)
    issues.extend(_structure_issues(located))
    issues.extend(_role_issues(located, DEFAULT_ROLES if roles is None else roles))
    if issues:
        issues.sort(key=lambda i: (i.line or 0, i.key))
        raise ConfigError(issues)
    assert mapping is not None
    return mapping, located


def _role_issues(located: Located, roles: Sequence[str]) -> list[ConfigIssue]:
    """Roles the mapping names that the gateway file does not define (their syntax is pydantic's)."""
    data = located.data
    places: list[tuple[Loc, Any]] = []
    defaults = data.get("defaults")
    if isinstance(defaults, dict):
        places.append((("defaults", "write_role"), defaults.get("write_role")))
    mqtt = data.get("mqtt")
    if isinstance(mqtt, dict):
        places.append((("mqtt", "writer_role"), mqtt.get("writer_role")))
    variables = data.get("variables")
    if isinstance(variables, list):
        for index, var in enumerate(variables):
            if isinstance(var, dict):
                places.append((("variables", index, "role"), var.get("role")))
    commands = data.get("commands")
    if isinstance(commands, dict):
        for name, command in commands.items():
            if isinstance(command, dict):
                places.append((("commands", name, "role"), command.get("role")))
    alarms = data.get("alarms")
    if isinstance(alarms, dict):
        places.append((("alarms", "acknowledge_role"), alarms.get("acknowledge_role")))
    issues = []
    for loc, role in places:
        if not isinstance(role, str) or not ROLE_RE.match(role) or role == REFUSE or role in roles:
            continue  # absent, or a syntax error pydantic reports, or fine
        message = unknown_role(role, roles)
        assert message is not None
        issues.append(ConfigIssue(located.file, located.line(loc), format_loc(loc), message))
    return issues


def _structure_issues(located: Located) -> list[ConfigIssue]:
    variables = located.data.get("variables")
    if not isinstance(variables, Sequence) or isinstance(variables, str):
        return []
    paths = []
    indices = []
    for index, var in enumerate(variables):
        if isinstance(var, dict) and isinstance(var.get("path"), str):
            paths.append(var["path"])
            indices.append(index)
    issues = []
    for pos, message in tree_conflicts(paths):
        loc: Loc = ("variables", indices[pos], "path")
        issues.append(ConfigIssue(located.file, located.line(loc), format_loc(loc), message))
    driver = located.data.get("driver")
    spec = registry.find(str(driver.get("type", registry.DEFAULT))) if isinstance(driver, dict) else None
    if spec is not None and spec.check_address is not None:
        issues.extend(_address_issues(located, variables, spec.check_address))
    return issues


def _address_issues(
    located: Located, variables: Sequence[Any], check: Callable[[str], object]
) -> list[ConfigIssue]:
    """Catch a typo in a driver address (a node id) at load time, not as a Bad variable at run time."""
    issues = []
    for index, var in enumerate(variables):
        source = var.get("source") if isinstance(var, dict) else None
        if not isinstance(source, str) or not source:
            continue
        try:
            check(source)
        except (AddressError, ValueError) as exc:
            loc: Loc = ("variables", index, "source")
            issues.append(ConfigIssue(located.file, located.line(loc), format_loc(loc), str(exc)))
    return issues


def is_gateway_file(located: Located) -> bool:
    return isinstance(located.data, dict) and "machine" not in located.data


def load(paths: Sequence[Path], environ: Mapping[str, str] | None = None) -> Config:
    """Load a gateway file, or one or more mapping files run with default settings.

    Every file is checked and every problem reported together; nothing starts
    half-configured.
    """
    if not paths:
        raise ConfigError([ConfigIssue("<command line>", None, "", "no configuration file given")])
    issues: list[ConfigIssue] = []
    gateway = GatewayConfig()
    gateway_file: Path | None = None
    gateway_located: Located | None = None
    base_dir = Path.cwd()
    mapping_files: list[Path] = []
    for path in paths:
        try:
            located = read_yaml(path, environ)
        except ConfigError as exc:
            issues.extend(exc.issues)
            continue
        if is_gateway_file(located):
            if len(paths) > 1:
                issues.append(ConfigIssue(str(path), 1, "", "a gateway file must be given on its own"))
                continue
            try:
                gateway = validate(GatewayConfig, located)
            except ConfigError as exc:
                raise ConfigError(exc.issues) from None
            base_dir = path.parent.resolve()
            gateway_file = path
            gateway_located = located
            issues.extend(
                _known_password_issues(located, gateway, os.environ if environ is None else environ)
            )
            if not gateway.machines:
                issues.append(
                    ConfigIssue(str(path), located.line(("machines",)), "machines", "lists no mapping files")
                )
            mapping_files.extend(base_dir / m for m in gateway.machines)
        else:
            mapping_files.append(path)
    machines: list[MachineMapping] = []
    seen: dict[str, Path] = {}
    for file in mapping_files:
        try:
            mapping, located = _read_mapping(file, environ, gateway.roles)
        except ConfigError as exc:
            issues.extend(exc.issues)
            continue
        issues.extend(_copydata_role_issues(located, mapping, gateway.access.copydata_role, gateway_file))
        if mapping.machine in seen:
            issues.append(
                ConfigIssue(
                    str(file),
                    None,
                    "machine",
                    f"machine {mapping.machine!r} is already defined in {seen[mapping.machine]}",
                )
            )
            continue
        seen[mapping.machine] = file
        machines.append(mapping)
    issues.extend(_shared_links(machines, seen))
    if issues:
        raise ConfigError(issues)
    elsewhere: dict[str, JobsConfig] = {}
    if gateway.leased and gateway.queue is None and gateway_located is not None and gateway_file is not None:
        raise ConfigError(
            [
                ConfigIssue(
                    str(gateway_file),
                    gateway_located.line(("shard",)),
                    "shard",
                    "shard: lease needs queue: postgresql://…: the leases are kept in the queue's database",
                )
            ]
        )
    if gateway.shard_of() is not None and gateway_located is not None and gateway_file is not None:
        fleet = machines
        machines = _shard_machines(gateway, machines, gateway_located, gateway_file)
        mapping_files = [seen[m.machine] for m in machines]
        mine = {m.machine for m in machines}
        elsewhere = {m.machine: m.jobs for m in fleet if m.machine not in mine and m.jobs is not None}
    return Config(gateway, tuple(machines), base_dir, tuple(mapping_files), elsewhere)


def _shard_machines(
    gateway: GatewayConfig, machines: list[MachineMapping], located: Located, file: Path
) -> list[MachineMapping]:
    """The machines of the gateway file's `shard:` (the whole fleet was checked first)."""
    shard = gateway.shard_of()
    assert shard is not None
    names = [m.machine for m in machines]
    issues: list[ConfigIssue] = []
    if isinstance(shard, list):
        for index, name in enumerate(shard):
            if name not in names:
                known = ", ".join(sorted(names))
                issues.append(
                    ConfigIssue(
                        str(file),
                        located.line(("shard", index)) or located.line(("shard",)),
                        f"shard[{index}]",
                        f"names {name!r}, which no mapping file defines (the fleet: {known})",
                    )
                )
    chosen = set(select(names, shard))
    if not chosen and not issues:
        issues.append(
            ConfigIssue(
                str(file),
                located.line(("shard",)),
                "shard",
                f"shard {shard} gets no machine: the fleet has {len(names)}",
            )
        )
    if issues:
        raise ConfigError(issues)
    return [m for m in machines if m.machine in chosen]


def _known_password_issues(
    located: Located, gateway: GatewayConfig, env: Mapping[str, str]
) -> list[ConfigIssue]:
    """Logins whose password is one cnc-gateway publishes (gateway/auth/known_passwords.py): refused, as
    good as none. Hashes are checked by scrypt; `password_env` by the value it names, if it is set."""
    hashes: dict[Loc, str] = {
        ("users", i, "password_hash"): u.password_hash for i, u in enumerate(gateway.users)
    }
    plain: dict[Loc, tuple[str, str]] = {}
    for index, account in enumerate(gateway.inbox.accounts):
        if account.password_hash is not None:
            hashes[("inbox", "accounts", index, "password_hash")] = account.password_hash
        if account.password_env is not None and account.password_env in env:
            plain[("inbox", "accounts", index, "password_env")] = (
                account.password_env,
                env[account.password_env],
            )
    found = known_passwords_of(hashes.values())
    problems = {loc: f"this is the hash of {found[h]!r}" for loc, h in hashes.items() if h in found}
    for loc, (name, value) in plain.items():
        if is_known(value):
            problems[loc] = f"environment variable {name} holds {value!r}"
    return [
        ConfigIssue(
            located.file,
            located.line(loc),
            format_loc(loc),
            f"{problem}, a password published in cnc-gateway's docs and examples, as good as none: choose "
            "another (a hash from `cnc-gateway hash-password`, or a password from the environment)",
        )
        for loc, problem in sorted(problems.items(), key=lambda item: located.line(item[0]) or 0)
    ]


def _copydata_role_issues(
    located: Located, mapping: MachineMapping, role: str | None, gateway_file: Path | None
) -> list[ConfigIssue]:
    """COPYDATA has no login: whoever reaches a target that accepts writes writes with the role the
    gateway file gives them (access.copydata_role). Without one the mapping is refused, never run with an
    implied role (before, the highest, admin, while no users were configured)."""
    if role is not None or mapping.copydata is None:
        return []
    where = (
        f"in the gateway file {gateway_file}"
        if gateway_file is not None
        else "in a gateway file (this mapping runs on its own, without one)"
    )
    issues = []
    for index, target in enumerate(mapping.copydata.targets):
        if not target.accept_writes:
            continue
        loc: Loc = ("copydata", "targets", index, "accept_writes")
        message = (
            f"target {target.name!r} accepts writes, but COPYDATA has no login: name the role its writes "
            f"act with, access.copydata_role {where} (every frame sent back through {target.describe()} "
            "writes with it), or set accept_writes: false"
        )
        issues.append(ConfigIssue(located.file, located.line(loc), format_loc(loc), message))
    return issues


def _shared_links(machines: Sequence[MachineMapping], files: Mapping[str, Path]) -> list[ConfigIssue]:
    """Serial lines that name the same `link` (one device server or uplink) must agree on its capacity."""
    capacities: dict[str, tuple[float, str]] = {}
    issues = []
    for mapping in machines:
        controller = mapping.jobs.controller if mapping.jobs is not None else None
        link = getattr(controller, "link", None)
        capacity = getattr(controller, "link_capacity", None)
        if link is None or capacity is None:
            continue
        seen = capacities.setdefault(link, (capacity, mapping.machine))
        if seen[0] != capacity:
            issues.append(
                ConfigIssue(
                    str(files[mapping.machine]),
                    None,
                    "jobs.controller.link_capacity",
                    f"link {link!r} carries {seen[0]:g} characters/s in machine {seen[1]!r} "
                    f"({files[seen[1]]}) but {capacity:g} here: one link, one capacity",
                )
            )
    return issues
