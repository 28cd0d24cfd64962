"""The web console's aiohttp adapter: every request goes to the console, its route and caller checked first.

aiohttp was chosen over Starlette with uvicorn because it is one library (server,
WebSocket, multipart) with no ASGI layer between, and the MTConnect agent uses it
too. Kept small on purpose: one catch-all route builds an `HttpRequest`
(gateway/sinks/web/http.py) and answers with the handler's `HttpResponse`; one
path upgrades to a WebSocket, handed over as a `LiveSocket`.

A request is admitted before a byte of its body is read (issue 23): `admit` (the console's router and
sessions) answers a refusal (404, 405, 401, 403) or an `Admitted` that says how many files the route
takes, and only then is the body read, with its limits: JSON and form bodies up to `max_body` within
`body_timeout`, multipart file parts streamed to the job inbox's staging folder up to `max_upload`, at
most `max_uploads` uploads at once, no pause longer than `body_timeout`. A file part sent to a route
that takes none is refused before it is written. `Expect: 100-continue` is answered after admission.
Connections are capped and slow ones closed by the listener both HTTP faces share
(gateway/sinks/http_listener.py). aiohttp's own errors (a body too large, malformed multipart, a port in
use) become refusals or a SinkError; nothing a client sends ends in a traceback.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import ssl
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, TypeVar

from aiohttp import BodyPartReader, WSMsgType, web
from aiohttp.web_exceptions import HTTPException

from gateway.errors import MalformedRequest, RequestError
from gateway.sinks.http_listener import Limits, Listener
from gateway.sinks.web.http import Admitted, HttpRequest, HttpResponse, UploadedFile, refusal

log = logging.getLogger("gateway.web")

Admit = Callable[[HttpRequest], "Admitted | HttpResponse"]
SocketHandler = Callable[[HttpRequest, "LiveSocket"], Awaitable[None]]
T = TypeVar("T")

MAX_FIELD = 64 * 1024  # bytes of one text field of a form
MAX_PARTS = 16  # parts of one multipart body
MAX_MESSAGE = 64 * 1024  # bytes of one WebSocket message from a browser
CHUNK = 256 * 1024
CONTINUE = b"HTTP/1.1 100 Continue\r\n\r\n"


class TooLarge(MalformedRequest):
    status = "BadRequestTooLarge"


class Stalled(RequestError):
    """The body stopped arriving (`body_timeout`)."""

    status = "BadTimeout"


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
        admit: Admit,
        socket_handler: SocketHandler,
        socket_path: str,
        upload_dir: Callable[[], Path],
        max_body: int,
        max_upload: int,
        max_uploads: int = 4,
        body_timeout: float = 30.0,
        limits: Limits | None = None,
        tls: ssl.SSLContext | None = None,
    ) -> None:
        self._admit = admit
        self._socket_handler = socket_handler
        self._socket_path = socket_path
        self._upload_dir = upload_dir
        self._max_body = max_body
        self._max_upload = max_upload
        self._max_uploads = max_uploads
        self._body_timeout = body_timeout
        self.uploads = 0  # uploads being received (and handled) now
        self.tls = tls
        self.listener = Listener(name="web console", limits=limits or Limits(), tls=tls, shutdown_timeout=1.0)

    @property
    def port(self) -> int:
        return self.listener.port

    async def start(self, host: str, port: int) -> None:
        app = web.Application(client_max_size=self._max_body, handler_args={"max_field_size": 16 * 1024})
        app.router.add_route("GET", self._socket_path, self._socket)
        app.router.add_route("*", "/{tail:.*}", self._dispatch, expect_handler=_after_admission)
        await self.listener.start(app, host, port)

    async def stop(self) -> None:
        await self.listener.stop()

    # --- requests -------------------------------------------------------------------------------

    async def _dispatch(self, request: web.Request) -> web.StreamResponse:
        req = _head(request)
        verdict = self._admit(req)
        if isinstance(verdict, HttpResponse):
            return _closing(verdict)  # the body, if any, is never read
        upload = verdict.files > 0 and request.content_type == "multipart/form-data" and request.can_read_body
        if upload and self.uploads >= self._max_uploads:
            busy = refusal(
                "BadTooManyOperations", f"{self.uploads} uploads are under way; try again shortly", 429
            )
            busy.headers["Retry-After"] = "5"
            return _closing(busy)
        files: list[UploadedFile] = []
        self.uploads += upload
        try:
            try:
                await _continue(request)
                await self._body(request, req, files, verdict.files)
            except Stalled as exc:
                return _closing(refusal(exc.status, exc.reason, 408))
            except MalformedRequest as exc:
                return _closing(refusal(exc.status, exc.reason))
            except HTTPException as exc:  # aiohttp's own refusal of the body (too large, …)
                status = "BadRequestTooLarge" if exc.status == 413 else "BadDecodingError"
                return _closing(refusal(status, exc.text or exc.reason, exc.status))
            except (ValueError, AssertionError, LookupError, UnicodeError) as exc:  # malformed multipart
                return _closing(refusal("BadDecodingError", f"malformed request body: {exc}"))
            try:
                response = await verdict.handle(req)
            except Exception:
                log.exception("web: %s %s failed", request.method, request.path)
                response = refusal("BadInternalError", "internal error (logged by the gateway)")
            return _wire(response)
        finally:
            self.uploads -= upload
            for f in files:  # what the handler did not take over (a job submission moves its file)
                await asyncio.to_thread(Path(f.path).unlink, missing_ok=True)

    async def _within(self, step: Awaitable[T]) -> T:
        """One step of reading a body, within `body_timeout`."""
        try:
            return await asyncio.wait_for(step, self._body_timeout)
        except TimeoutError:
            raise Stalled(f"the request body stalled for {self._body_timeout:g} s") from None

    async def _body(
        self, request: web.Request, req: HttpRequest, files: list[UploadedFile], allowed: int
    ) -> None:
        if request.method in ("GET", "HEAD", "OPTIONS") or not request.can_read_body:
            return
        ctype = request.content_type
        if ctype == "multipart/form-data":
            await self._multipart(request, req, files, allowed)
        elif ctype == "application/x-www-form-urlencoded":
            form = await self._within(request.post())
            req.form = {k: v for k, v in form.items() if isinstance(v, str)}
        else:
            if request.content_length is not None and request.content_length > self._max_body:
                raise TooLarge(
                    f"the body has {request.content_length} bytes, more than the {self._max_body} allowed"
                )
            req.body = await self._within(request.read())

    async def _multipart(
        self, request: web.Request, req: HttpRequest, files: list[UploadedFile], allowed: int
    ) -> None:
        reader = await request.multipart()
        parts = 0
        while True:
            part = await self._within(reader.next())
            if part is None:
                return
            parts += 1
            if parts > MAX_PARTS:
                raise MalformedRequest(f"more than {MAX_PARTS} parts in one request")
            if not isinstance(part, BodyPartReader):
                raise MalformedRequest("nested multipart bodies are not understood")
            name = part.name or ""
            if part.filename is None:
                data = await self._field(part, name)
                try:
                    req.form[name] = data.decode("utf-8")
                except UnicodeDecodeError as exc:
                    raise MalformedRequest(f"field {name!r} is not UTF-8 text (byte {exc.start})") from None
                continue
            if len(files) >= allowed:
                raise MalformedRequest(
                    f"{req.path} takes no files" if not allowed else f"send at most {allowed} file(s)"
                )
            files.append(await self._spool(part, name, part.filename))
            req.files.append(files[-1])

    async def _field(self, part: BodyPartReader, name: str) -> bytes:
        """A text field, read in chunks up to MAX_FIELD bytes (never the whole of an oversized one)."""
        data = bytearray()
        while chunk := await self._within(part.read_chunk(CHUNK)):
            data += chunk
            if len(data) > MAX_FIELD:
                raise TooLarge(f"field {name!r} is larger than {MAX_FIELD} bytes")
        return bytes(part.decode(bytes(data)))

    async def _spool(self, part: BodyPartReader, name: str, filename: str) -> UploadedFile:
        """A file part, streamed to a staging file with its size and SHA-256, up to `max_upload` bytes."""
        path = self._upload_dir()
        path.parent.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha256()
        size = 0
        loop = asyncio.get_running_loop()
        with path.open("wb") as out:
            try:
                while chunk := await self._within(part.read_chunk(CHUNK)):
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
        req = _head(request)
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


def _head(request: web.Request) -> HttpRequest:
    """The request as the console sees it, before its body."""
    return HttpRequest(
        method=request.method,
        path=request.path,
        query=_multi(request.query),
        headers={k.lower(): v for k, v in request.headers.items()},
        cookies=dict(request.cookies),
        remote=request.remote or "",
        secure=request.secure,
    )


async def _after_admission(request: web.Request) -> None:
    """aiohttp's Expect handler, which runs before the handler: nothing yet (`_continue` answers it)."""


async def _continue(request: web.Request) -> None:
    """`Expect: 100-continue`, answered once the request is admitted: the client may send its body now."""
    expect = request.headers.get("Expect", "")
    if not expect or request.version < (1, 1):
        return
    if expect.lower() != "100-continue":
        raise MalformedRequest(f"Expect: {expect[:40]!r} is not understood (only 100-continue)")
    await request.writer.write(CONTINUE)
    request.writer.output_size = 0


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


def _closing(response: HttpResponse) -> web.Response:
    """A refusal after which the connection closes: a body the client may still be sending is not read
    (aiohttp discards what arrives for a few seconds, so that the client can read the answer)."""
    out = _wire(response)
    out.force_close()
    return out


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
