"""A small router: `METHOD /path/{name}/{rest*}` patterns to handlers. Pure, no web framework.

`{name}` matches one path segment, `{name*}` the rest of the path (a variable's
path has slashes). `match()` answers the handler with its parameters, or the
methods the path allows (405), or nothing (404). A route that takes uploads says
how many files (`files`) and may check its caller before the body is read (`admit`).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

Handler = Callable[..., Awaitable[Any]]
Check = Callable[..., None]  # (request, caller): raises a RequestError to refuse before the body is read


@dataclass(frozen=True, slots=True)
class Route:
    method: str
    pattern: str
    handler: Handler
    public: bool  # no caller needed (health, metrics, login, static files)
    segments: tuple[str, ...]
    files: int = 0  # multipart file parts it takes; others are refused before they are written
    admit: Check | None = None  # its own check of the caller, before the body is read

    def match(self, parts: list[str]) -> dict[str, str] | None:
        params: dict[str, str] = {}
        for index, seg in enumerate(self.segments):
            if seg.startswith("{") and seg.endswith("*}"):
                rest = parts[index:]
                if not rest or not all(rest):
                    return None
                params[seg[1:-2]] = "/".join(rest)
                return params
            if index >= len(parts):
                return None
            if seg.startswith("{") and seg.endswith("}"):
                if not parts[index]:
                    return None
                params[seg[1:-1]] = parts[index]
            elif seg != parts[index]:
                return None
        return params if len(parts) == len(self.segments) else None


class Router:
    def __init__(self) -> None:
        self.routes: list[Route] = []

    def add(
        self,
        method: str,
        pattern: str,
        handler: Handler,
        *,
        public: bool = False,
        files: int = 0,
        admit: Check | None = None,
    ) -> None:
        segments = tuple(pattern.strip("/").split("/"))
        self.routes.append(Route(method, pattern, handler, public, segments, files, admit))

    def match(self, method: str, path: str) -> tuple[Route, dict[str, str]] | list[str] | None:
        parts = path.strip("/").split("/") if path.strip("/") else [""]
        allowed: list[str] = []
        for route in self.routes:
            params = route.match(parts)
            if params is None:
                continue
            if route.method == method or (method == "HEAD" and route.method == "GET"):
                return route, params
            allowed.append(route.method)
        return allowed or None
