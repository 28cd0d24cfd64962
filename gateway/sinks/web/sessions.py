"""Who is asking: console sessions (cookies), API tokens, anonymous visitors; and the CSRF check.

- **Logins** use the gateway's users (gateway/auth/users.py): the same scrypt hashes,
  roles and lockout per address as OPC UA. A login makes a session: a random id in a
  cookie that is HttpOnly (scripts cannot read it), SameSite=Strict (other sites'
  pages cannot send it) and Secure behind TLS; it ends after `session_idle` seconds
  without a request, or at logout.
- **Unsafe methods** (POST, PUT, PATCH, DELETE) made with a session must carry the
  session's CSRF token (header `X-CSRF-Token`, or a form field `csrf`); the pages
  have it in a meta tag. SameSite=Strict already keeps other sites out; the token
  is the second lock, for browsers or proxies that do not honour it.
- **API tokens** (`Authorization: Bearer cgw_…`, made by `cnc-gateway tokens create`)
  act with their user's role; no cookie, so no CSRF token is needed.
- **Anonymous visitors** get `access.anonymous`'s role, or must log in when it is `refuse`.

Every request gets a `Caller`, whose `context()` is the WriteContext of the one
write path (origin `http`), so roles are checked and audited there, as for every door.
"""

from __future__ import annotations

import asyncio
import hmac
import secrets
import time
from collections import OrderedDict
from dataclasses import dataclass, field

from gateway.auth.tokens import TokenStore
from gateway.auth.users import UserDirectory
from gateway.errors import AccessDenied
from gateway.model.context import WriteContext
from gateway.sinks.web.http import HttpRequest

COOKIE = "cnc_session"
CSRF_HEADER = "x-csrf-token"
UNSAFE = frozenset({"POST", "PUT", "PATCH", "DELETE"})
MAX_SESSIONS = 10_000
ORIGIN = "http"


@dataclass(slots=True)
class Session:
    id: str
    user: str
    role: str | None
    csrf: str
    seen: float = field(default_factory=time.monotonic)


@dataclass(frozen=True, slots=True)
class Caller:
    """The user behind a request (None: anonymous), its role, and how it came in."""

    user: str | None
    role: str | None
    via: str  # "session", "token" or "anonymous"
    session: Session | None = None

    def context(self) -> WriteContext:
        return WriteContext(ORIGIN, self.user, self.role)

    @property
    def csrf(self) -> str:
        return self.session.csrf if self.session is not None else ""

    @property
    def name(self) -> str:
        return self.user or "anonymous"


class LoginRequired(AccessDenied):
    """No session, and anonymous visitors are refused (access.anonymous: refuse), or a token is wrong."""

    status = "BadIdentityTokenInvalid"


class Sessions:
    def __init__(self, users: UserDirectory, tokens: TokenStore, *, idle: float) -> None:
        self.users = users
        self.tokens = tokens
        self.idle = idle
        self._sessions: OrderedDict[str, Session] = OrderedDict()

    # --- logging in and out -----------------------------------------------------------------------

    async def login(self, name: str, password: str, address: str) -> Session | None:
        """A new session, or None (wrong password, unknown user, locked out: logged by the directory)."""
        if not name or not password or len(name) > 64 or len(password) > 1024:
            return None
        identity = await asyncio.to_thread(self.users.authenticate, name, password, address, "HTTP")
        if identity is None or identity.name is None:
            return None
        session = Session(secrets.token_urlsafe(32), identity.name, identity.role, secrets.token_urlsafe(24))
        self._sessions[session.id] = session
        while len(self._sessions) > MAX_SESSIONS:
            self._sessions.popitem(last=False)
        return session

    def logout(self, caller: Caller) -> None:
        if caller.session is not None:
            self._sessions.pop(caller.session.id, None)

    def cookie(self, session: Session | None, *, secure: bool) -> str:
        """The Set-Cookie value that sets the session's cookie (or clears it, for None)."""
        attrs = "; Path=/; HttpOnly; SameSite=Strict" + ("; Secure" if secure else "")
        if session is None:
            return f"{COOKIE}=; Max-Age=0{attrs}"
        return f"{COOKIE}={session.id}{attrs}"

    # --- every request ----------------------------------------------------------------------------

    def caller(self, req: HttpRequest) -> Caller:
        """Who is asking; LoginRequired when nobody may ask anonymously or a bearer token is not valid."""
        auth = req.headers.get("authorization", "")
        if auth:
            scheme, _, token = auth.partition(" ")
            if scheme.lower() != "bearer" or not token.strip():
                raise LoginRequired("the Authorization header must be `Bearer <token>`")
            user = self.tokens.verify(token.strip())
            role = self.users.role_of(user) if user is not None else None
            if user is None or role is None:
                raise LoginRequired("the API token is not valid (unknown, revoked, or its user is gone)")
            return Caller(user, role, "token")
        session = self._session(req.cookies.get(COOKIE, ""))
        if session is not None:
            return Caller(session.user, self.users.role_of(session.user) or session.role, "session", session)
        if not self.users.anonymous_allowed:
            raise LoginRequired("log in first: anonymous visitors are refused (access.anonymous: refuse)")
        return Caller(None, self.users.anonymous_role, "anonymous")

    def check_csrf(self, req: HttpRequest, caller: Caller) -> None:
        """Unsafe requests made with a session must carry its CSRF token (AccessDenied otherwise)."""
        if req.method not in UNSAFE or caller.session is None:
            return
        sent = req.headers.get(CSRF_HEADER) or req.form.get("csrf") or ""
        if not hmac.compare_digest(sent.encode(), caller.session.csrf.encode()):
            raise AccessDenied("the request lacks the page's CSRF token; reload the page and try again")

    def _session(self, sid: str) -> Session | None:
        if not sid:
            return None
        session = self._sessions.get(sid)
        if session is None:
            return None
        now = time.monotonic()
        if now - session.seen > self.idle:
            del self._sessions[sid]
            return None
        session.seen = now
        self._sessions.move_to_end(sid)
        return session
