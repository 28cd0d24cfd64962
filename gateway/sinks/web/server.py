"""The one module that imports aiohttp: an HTTP(S) server that hands every request to the console.

aiohttp was chosen over Starlette with uvicorn because it is one library (server,
WebSocket, multipart) with no ASGI layer between, and the MTConnect agent uses it
too. Kept small on purpose: one catch-all route builds an `HttpRequest`
(gateway/sinks/web/http.py) and answers with the handler's `HttpResponse`; one
path upgrades to a WebSocket, handed over as a `LiveSocket`. Request bodies are
read here, with their limits: JSON and form bodies up to `max_body`, multipart
file parts streamed to the job inbox's staging folder up to `max_upload`.
Connections are capped and slow ones closed by the listener both HTTP faces
share (gateway/sinks/http_listener.py, `http.connections`). aiohttp's own errors
(a body too large, malformed multipart, a port in use) become refusals or a
SinkError; nothing a client sends ends in a traceback.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import ssl
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from aiohttp import BodyPartReader, WSMsgType, web
from aiohttp.web_exceptions import HTTPException

from gateway.errors import MalformedRequest
from gateway.sinks.http_listener import Limits, Listener
from gateway.sinks.web.http import HttpRequest, HttpResponse, UploadedFile, refusal

log = logging.getLogger("gateway.web")

Handler = Callable[[HttpRequest], Awaitable[HttpResponse]]
SocketHandler = Callable[[HttpRequest, "LiveSocket"], Awaitable[None]]

MAX_FIELD = 64 * 1024  # bytes of one text field of a form
MAX_PARTS = 16  # parts of one multipart body
MAX_MESSAGE = 64 * 1024  # bytes of one WebSocket message from a browser
CHUNK = 256 * 1024


class TooLarge(MalformedRequest):
    status = "BadRequestTooLarge"


class LiveSocket:
    """A WebSocket as the console sees it: text messages in and out."""

    def __init__(self, ws: web.WebSocketResponse) -> None:
        self._ws = ws

    async def receive(self) -> str | None:
        """The next text message; None once the socket is closed. A binary message is a MalformedRequest."""
        while True:
            msg = await self._ws.receive()
            if msg.type == WSMsgType.TEXT:
                return str(msg.data)
            if msg.type == WSMsgType.BINARY:
                raise MalformedRequest("binary messages are not understood; send JSON text")
            if msg.type in (WSMsgType.CLOSE, WSMsgType.CLOSING, WSMsgType.CLOSED, WSMsgType.ERROR):
                return None

    async def send(self, text: str) -> bool:
        """False when the socket is gone (the message is dropped)."""
        if self._ws.closed:
            return False
        try:
            await self._ws.send_str(text)
        except (ConnectionError, RuntimeError):
            return False
        return True

    @property
    def closed(self) -> bool:
        return self._ws.closed

    async def close(self) -> None:
        await self._ws.close()


class HttpServer:
    """`await start()`, `await stop()`; `port` is the bound port (also when 0 was asked)."""

    def __init__(
        self,
        *,
        handler: Handler,
        socket_handler: SocketHandler,
        socket_path: str,
        upload_dir: Callable[[], Path],
        max_body: int,
        max_upload: int,
        limits: Limits | None = None,
        tls: ssl.SSLContext | None = None,
    ) -> None:
        self._handler = handler
        self._socket_handler = socket_handler
        self._socket_path = socket_path
        self._upload_dir = upload_dir
        self._max_body = max_body
        self._max_upload = max_upload
        self.tls = tls
        self.listener = Listener(name="web console", limits=limits or Limits(), tls=tls, shutdown_timeout=1.0)

    @property
    def port(self) -> int:
        return self.listener.port

    async def start(self, host: str, port: int) -> None:
        app = web.Application(client_max_size=self._max_body, handler_args={"max_field_size": 16 * 1024})
        app.router.add_route("GET", self._socket_path, self._socket)
        app.router.add_route("*", "/{tail:.*}", self._dispatch)
        await self.listener.start(app, host, port)

    async def stop(self) -> None:
        await self.listener.stop()

    # --- requests -------------------------------------------------------------------------------

    async def _dispatch(self, request: web.Request) -> web.StreamResponse:
        files: list[UploadedFile] = []
        try:
            try:
                req = await self._request(request, files)
            except MalformedRequest as exc:
                return _wire(refusal(exc.status, exc.reason))
            except HTTPException as exc:  # aiohttp's own refusal of the body (too large, …)
                status = "BadRequestTooLarge" if exc.status == 413 else "BadDecodingError"
                return _wire(refusal(status, exc.text or exc.reason, exc.status))
            except (ValueError, AssertionError, LookupError, UnicodeError) as exc:  # malformed multipart
                return _wire(refusal("BadDecodingError", f"malformed request body: {exc}"))
            try:
                response = await self._handler(req)
            except Exception:
                log.exception("web: %s %s failed", request.method, request.path)
                response = refusal("BadInternalError", "internal error (logged by the gateway)")
            return _wire(response)
        finally:
            for f in files:  # what the handler did not take over (a job submission moves its file)
                await asyncio.to_thread(Path(f.path).unlink, missing_ok=True)

    async def _request(self, request: web.Request, files: list[UploadedFile]) -> HttpRequest:
        headers = {k.lower(): v for k, v in request.headers.items()}
        req = HttpRequest(
            method=request.method,
            path=request.path,
            query=_multi(request.query),
            headers=headers,
            cookies=dict(request.cookies),
            remote=request.remote or "",
            secure=request.secure,
        )
        if request.method in ("GET", "HEAD", "OPTIONS") or not request.can_read_body:
            return req
        ctype = request.content_type
        if ctype == "multipart/form-data":
            await self._multipart(request, req, files)
        elif ctype == "application/x-www-form-urlencoded":
            form = await request.post()
            req.form = {k: v for k, v in form.items() if isinstance(v, str)}
        else:
            if request.content_length is not None and request.content_length > self._max_body:
                raise TooLarge(
                    f"the body has {request.content_length} bytes, more than the {self._max_body} allowed"
                )
            req.body = await request.read()
        return req

    async def _multipart(self, request: web.Request, req: HttpRequest, files: list[UploadedFile]) -> None:
        reader = await request.multipart()
        parts = 0
        while True:
            part = await reader.next()
            if part is None:
                return
            parts += 1
            if parts > MAX_PARTS:
                raise MalformedRequest(f"more than {MAX_PARTS} parts in one request")
            if not isinstance(part, BodyPartReader):
                raise MalformedRequest("nested multipart bodies are not understood")
            name = part.name or ""
            if part.filename is None:
                data = await part.read(decode=True)
                if len(data) > MAX_FIELD:
                    raise TooLarge(f"field {name!r} is larger than {MAX_FIELD} bytes")
                try:
                    req.form[name] = bytes(data).decode("utf-8")
                except UnicodeDecodeError as exc:
                    raise MalformedRequest(f"field {name!r} is not UTF-8 text (byte {exc.start})") from None
                continue
            files.append(await self._spool(part, name, part.filename))
            req.files.append(files[-1])

    async def _spool(self, part: BodyPartReader, name: str, filename: str) -> UploadedFile:
        """A file part, streamed to a staging file with its size and SHA-256, up to `max_upload` bytes."""
        path = self._upload_dir()
        path.parent.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha256()
        size = 0
        loop = asyncio.get_running_loop()
        with path.open("wb") as out:
            try:
                while chunk := await part.read_chunk(CHUNK):
                    size += len(chunk)
                    if size > self._max_upload:
                        raise TooLarge(f"the file is larger than the {self._max_upload} bytes allowed")
                    digest.update(chunk)
                    await loop.run_in_executor(None, out.write, chunk)
            except BaseException:
                out.close()
                path.unlink(missing_ok=True)
                raise
        return UploadedFile(name, filename, path, size, digest.hexdigest())

    # --- the live socket ------------------------------------------------------------------------

    async def _socket(self, request: web.Request) -> web.StreamResponse:
        req = HttpRequest(
            method="GET",
            path=request.path,
            query=_multi(request.query),
            headers={k.lower(): v for k, v in request.headers.items()},
            cookies=dict(request.cookies),
            remote=request.remote or "",
            secure=request.secure,
        )
        # No permessage-deflate: compressing every batch for every page cost the mirror more than a LAN saves.
        ws = web.WebSocketResponse(heartbeat=30.0, max_msg_size=MAX_MESSAGE, compress=False)
        if not ws.can_prepare(request).ok:
            return _wire(refusal("BadDecodingError", "this address takes WebSocket connections only"))
        await ws.prepare(request)
        try:
            await self._socket_handler(req, LiveSocket(ws))
        except Exception:
            log.exception("web: the live socket from %s failed", req.remote)
        finally:
            await ws.close()
        return ws


def _multi(query: Any) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for key, value in query.items():
        out.setdefault(key, []).append(value)
    return out


SECURITY_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "same-origin",
    "Content-Security-Policy": (
        "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'; base-uri 'none'"
    ),
}


def _wire(response: HttpResponse) -> web.Response:
    out = web.Response(status=response.status, body=response.body)
    out.headers["Content-Type"] = response.content_type
    for key, value in SECURITY_HEADERS.items():
        out.headers.setdefault(key, value)
    for key, value in response.headers.items():
        out.headers[key] = value
    for cookie in response.cookies:
        out.headers.add("Set-Cookie", cookie)
    return out
