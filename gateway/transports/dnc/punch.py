"""The mapping's `jobs.punch:` section: what the gateway does with what a serial machine sends it.

An operator's PUNCH is stored under the state directory (and optionally
validated and filed as a backup); a punched remote request (`O9999 (PRG=O4711)`)
is answered with the named program from `requests.folder` and/or the programs
the machine's job queue accepted (`requests.from`). Without `punch:` the gateway
ignores what the controller sends while no job is sending.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import ConfigDict, Field, field_validator, model_validator

from gateway.settings.base import Strict

_KEY_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_")


Source = Literal["folder", "queue"]


def _folder_only() -> list[Source]:
    return ["folder"]


class RemoteRequests(Strict):
    """Punched requests for a program, answered from a folder of the gateway's host and/or from the
    programs the machine's job queue accepted."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    folder: Path | None = Field(
        default=None,
        description="Folder of the programs an operator may request (nothing outside it); needed when "
        "`from` names folder",
    )
    sources: list[Source] = Field(
        default_factory=_folder_only,
        alias="from",
        min_length=1,
        description="Where a requested program is looked for, in this order: folder (requests.folder) and "
        "queue (the newest job of this machine the queue accepted whose file name or program number "
        "matches; not rejected or cancelled ones)",
    )
    keep_delivered: int = Field(
        default=50,
        ge=0,
        le=100_000,
        description="With from: queue, the validated programs of this many delivered jobs are kept "
        "(spool/delivered/<machine>/) so that a request can name them",
    )
    number: int = Field(
        default=9999, ge=1, le=99_999_999, description="O-number that marks a punched program as a request"
    )
    key: str = Field(default="PRG", description="Key in the request's comment: (PRG=O4711)")
    extensions: list[str] = Field(
        default_factory=lambda: ["", ".nc", ".NC", ".txt"],
        description="Tried in turn after the requested name to find its file",
    )
    send: Literal["now", "load", "queue"] = Field(
        default="now",
        description="now: send the program back at once, load or drip as jobs.controller.mode says; load: at "
        "once, always as a load; queue: submit it as a job (validated, delivered load or drip as "
        "jobs.controller says, visible in cnc-gateway jobs)",
    )
    max_size: int = Field(
        default=1024 * 1024,
        ge=1,
        description="Largest program answered at once (send: now or load); a larger one is refused, use "
        "send: queue",
    )
    user: str = Field(
        default="operator",
        min_length=1,
        description="Who the audit trail and the transfer log name as the requester (the person at the "
        "machine, who has no login)",
    )

    @field_validator("key")
    @classmethod
    def _key(cls, key: str) -> str:
        if not key or not set(key.upper()) <= _KEY_CHARS:
            raise ValueError(f"key {key!r}: letters, digits and _ only (e.g. PRG)")
        return key

    @field_validator("sources")
    @classmethod
    def _sources(cls, sources: list[Source]) -> list[Source]:
        if len(set(sources)) != len(sources):
            raise ValueError("each of folder and queue at most once")
        return sources

    @model_validator(mode="after")
    def _folder(self) -> RemoteRequests:
        if "folder" in self.sources and self.folder is None:
            raise ValueError("folder: needed when from names folder (or from: [queue])")
        return self

    @field_validator("extensions")
    @classmethod
    def _extensions(cls, extensions: list[str]) -> list[str]:
        for ext in extensions:
            if "/" in ext or "\\" in ext or ".." in ext or (ext and not ext.startswith(".")):
                raise ValueError(f"extension {ext!r}: empty, or a dot and letters (.nc)")
        return extensions


class PunchSettings(Strict):
    """Programs the operator punches, and remote requests."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    validate_programs: bool = Field(
        default=False,
        alias="validate",
        description="Check a punched program with the machine's validation rules (the verdict is reported, "
        "the program kept either way)",
    )
    backup: bool = Field(
        default=False, description="Also file each punched program in the backups folder (backups/<machine>/)"
    )
    max_size: int = Field(default=16 * 1024 * 1024, ge=1, description="Largest punched program, in bytes")
    idle_timeout: float = Field(
        default=10.0,
        gt=0,
        description="Seconds of silence inside a program (after its opening %) before it is refused as "
        "unterminated",
    )
    requests: RemoteRequests | None = Field(
        default=None, description="Answer punched requests for a program (none without this)"
    )
