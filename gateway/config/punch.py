"""The mapping's `jobs.punch:` section: what the gateway does with what a serial machine sends it.

An operator's PUNCH is stored under the state directory (and optionally
validated and filed as a backup); a punched remote request (`O9999 (PRG=O4711)`)
is answered with the named program from `requests.folder`. Without `punch:`
the gateway ignores what the controller sends while no job is sending.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import ConfigDict, Field, field_validator

from gateway.config.base import Strict

_KEY_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_")


class RemoteRequests(Strict):
    """Punched requests for a program, answered from a folder of the gateway's host."""

    folder: Path = Field(description="Folder of the programs an operator may request (nothing outside it)")
    number: int = Field(
        default=9999, ge=1, le=99_999_999, description="O-number that marks a punched program as a request"
    )
    key: str = Field(default="PRG", description="Key in the request's comment: (PRG=O4711)")
    extensions: list[str] = Field(
        default_factory=lambda: ["", ".nc", ".NC", ".txt"],
        description="Tried in turn after the requested name to find its file",
    )
    send: Literal["load", "queue"] = Field(
        default="load",
        description="load: send the program back at once as a load; queue: submit it as a job (validated, "
        "delivered load or drip as jobs.controller says, visible in cnc-gateway jobs)",
    )
    max_size: int = Field(
        default=1024 * 1024,
        ge=1,
        description="Largest program answered at once (send: load); a larger one is refused, use send: queue",
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
