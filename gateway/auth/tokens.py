"""API tokens for the REST API: one or more per user, kept hashed in the state directory.

A token is `cgw_<id>_<secret>`: `id` names the entry (8 hex digits, shown by
`cnc-gateway tokens list` and used to revoke it), `secret` is 32 random bytes.
Only the SHA-256 of the secret is stored. A fast hash is enough here, unlike
for passwords: a 256-bit random secret cannot be guessed from its hash, and the
API checks a token on every request, where scrypt's ~50 ms would be paid each
time. A token acts with its user's role *now* (looked up in the gateway file at
each request), so a demoted or removed user's tokens follow.

The file (`<state_dir>/http-tokens.json`, mode 0600) is written by
`cnc-gateway tokens create|revoke` and read by the running gateway, which
reloads it when it changes. Pure file handling, no network.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import re
import secrets
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

FILE_NAME = "http-tokens.json"
PREFIX = "cgw"
TOKEN_RE = re.compile(r"^cgw_([0-9a-f]{8})_([A-Za-z0-9_\-]{43})$")


class TokenError(ValueError):
    """The token file cannot be read or written, or a token id is unknown."""


@dataclass(frozen=True, slots=True)
class TokenEntry:
    id: str
    user: str
    sha256: str
    created: str  # ISO-8601 UTC
    label: str = ""


def tokens_path(state_dir: Path) -> Path:
    return state_dir / FILE_NAME


def _digest(secret: str) -> str:
    return hashlib.sha256(secret.encode("ascii")).hexdigest()


class TokenStore:
    """The token file: `create`, `revoke`, `entries`, `verify` (which re-reads the file when it changed)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._stamp: tuple[float, int] | None = None
        self._entries: dict[str, TokenEntry] = {}

    def entries(self) -> list[TokenEntry]:
        self._reload()
        return sorted(self._entries.values(), key=lambda e: e.created)

    def create(self, user: str, label: str = "") -> str:
        """A new token for `user`; the only time its secret is seen."""
        self._reload()
        token_id = secrets.token_hex(4)
        while token_id in self._entries:
            token_id = secrets.token_hex(4)
        secret = secrets.token_urlsafe(32)
        created = datetime.now(UTC).isoformat(timespec="seconds")
        self._entries[token_id] = TokenEntry(token_id, user, _digest(secret), created, label)
        self._write()
        return f"{PREFIX}_{token_id}_{secret}"

    def revoke(self, token_id: str) -> TokenEntry:
        self._reload()
        entry = self._entries.pop(token_id, None)
        if entry is None:
            raise TokenError(f"no token {token_id!r} in {self.path}")
        self._write()
        return entry

    def verify(self, token: str) -> str | None:
        """The user a token belongs to, or None (malformed, unknown, revoked or wrong secret)."""
        match = TOKEN_RE.match(token)
        if match is None:
            return None
        try:
            self._reload()
        except TokenError:
            return None
        entry = self._entries.get(match.group(1))
        if entry is None or not hmac.compare_digest(entry.sha256, _digest(match.group(2))):
            return None
        return entry.user

    def _reload(self) -> None:
        try:
            st = self.path.stat()
        except FileNotFoundError:
            self._stamp, self._entries = None, {}
            return
        except OSError as exc:
            raise TokenError(f"cannot read {self.path}: {exc.strerror or exc}") from None
        stamp = (st.st_mtime, st.st_size)
        if stamp == self._stamp:
            return
        try:
            raw = json.loads(self.path.read_text(encoding="utf-8"))
            entries = {e["id"]: TokenEntry(**e) for e in raw["tokens"]}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise TokenError(f"{self.path} is not a token file: {exc}") from None
        self._stamp, self._entries = stamp, entries

    def _write(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = {"tokens": [asdict(e) for e in sorted(self._entries.values(), key=lambda e: e.created)]}
        tmp = self.path.with_name(self.path.name + ".tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            json.dump(data, out, indent=1)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, self.path)
        self._stamp = None
