"""WM_COPYDATA to a nesting package's window, and its replies to ours: the Windows transport.

Everything that touches a window runs on one dedicated thread, because Windows
ties a window to the thread that created it and delivers messages sent to it
only while that thread calls into the message functions:

- `MessageWindow`: a hidden message-only window (parent HWND_MESSAGE) whose
  handle goes in wParam of every frame, so the receiver can answer with
  WM_COPYDATA of its own. Its window procedure copies the reply out of the
  COPYDATASTRUCT before returning (the data is valid only during the call).
- `CopydataSender`: FindWindowW by class and/or title (then message-only
  windows through FindWindowExW(HWND_MESSAGE, …)), and SendMessageTimeoutW
  with SMTO_ABORTIFHUNG and a timeout. The COPYDATASTRUCT is the native,
  pointer-sized one, and the buffer lpData points to is held in a local until
  SendMessageTimeoutW returns, when the receiver has its copy. SMTO_BLOCK is
  not used: while waiting, our thread must still take the receiver's reply if
  it answers synchronously from its window procedure.
- `WindowThread`: runs the window, the sends and the message pump, woken by a
  Win32 event when the event loop has frames for it.
- `Win32Transport`: the asyncio side, like the TCP and UDP transports.

This module only loads user32/kernel32 in `load_api()`, which refuses to run
anywhere but on Windows; tests on other systems inject a stand-in for them.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import ctypes
import itertools
import logging
import os
import queue
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from gateway.codecs.copydata import WM_COPYDATA, CopydataError, decode_lpdata
from gateway.errors import SinkError
from gateway.reconnect import Backoff, OutageLog
from gateway.sinks.copydata.channel import OutFrame
from gateway.sinks.copydata.port import TransportPort
from gateway.sinks.copydata.win32_api import (
    COPYDATASTRUCT,
    DWORD_PTR,
    ERROR_INVALID_WINDOW_HANDLE,
    ERROR_TIMEOUT,
    HANDLE,
    KERNEL32,
    MSG,
    MSGFLT_ALLOW,
    PM_REMOVE,
    QS_ALLINPUT,
    SEND_FLAGS,
    USER32,
    WAIT_FAILED,
    WNDCLASSEXW,
    WNDPROC,
    bind,
    hwnd_message,
)

log = logging.getLogger("gateway.sinks.copydata")

WAKE_EVERY_MS = 250  # the window thread checks for a stop request at least this often
REPLY_QUEUE = 100
_class_ids = itertools.count(1)

# (wParam: the replying window, dwData, the bytes lpData pointed to) -- called on the window thread
ReplyCallback = Callable[[int, int, bytes], None]


def load_api() -> tuple[Any, Any]:
    """user32 and kernel32 with explicit signatures. Windows only."""
    if sys.platform != "win32":
        raise SinkError(f"WM_COPYDATA needs Windows; this is {sys.platform}")
    user32 = bind(ctypes.WinDLL("user32", use_last_error=True), USER32)
    kernel32 = bind(ctypes.WinDLL("kernel32", use_last_error=True), KERNEL32)
    return user32, kernel32


def last_error() -> int:
    return ctypes.get_last_error() if sys.platform == "win32" else 0  # type: ignore[attr-defined]


def read_copydatastruct(address: int, max_cbdata: int) -> tuple[int, bytes]:
    """dwData and a copy of the cbData bytes at lpData, from the COPYDATASTRUCT at `address`.

    Raises ValueError for a cbData over `max_cbdata` (nothing is copied then) or a NULL lpData.
    """
    cds = COPYDATASTRUCT.from_address(address)
    size = int(cds.cbData)
    if size > max_cbdata:
        raise ValueError(f"cbData {size} is over max_cbdata {max_cbdata}")
    if size == 0:
        return int(cds.dwData), b""
    if not cds.lpData:
        raise ValueError(f"cbData is {size} but lpData is NULL")
    return int(cds.dwData), ctypes.string_at(cds.lpData, size)


# --- the sender ------------------------------------------------------------------------------------


class SendFailed(Exception):
    """SendMessageTimeoutW returned 0: `timed_out` (hung or slow receiver) or `window_gone`."""

    def __init__(self, message: str, *, error: int, timed_out: bool, window_gone: bool) -> None:
        super().__init__(message)
        self.error = error
        self.timed_out = timed_out
        self.window_gone = window_gone


@dataclass
class SendOutcome:
    sent: int
    refused: int  # the receiver's window procedure returned FALSE
    failure: SendFailed | None = None


class CopydataSender:
    """Finds the receiver's window and sends it frames; call only from the window thread."""

    def __init__(
        self,
        user32: Any,
        *,
        window_class: str | None,
        window_title: str | None,
        timeout_ms: int,
        get_last_error: Callable[[], int] = last_error,
    ) -> None:
        if window_class is None and window_title is None:
            raise ValueError("a window class or title is needed to find the receiver")
        self.user32 = user32
        self.window_class = window_class
        self.window_title = window_title
        self.timeout_ms = max(1, int(timeout_ms))
        self.get_last_error = get_last_error

    def find(self) -> int:
        """The receiver's window handle, or 0 when no such window exists (yet)."""
        user32 = self.user32
        hwnd = user32.FindWindowW(self.window_class, self.window_title)
        if not hwnd:  # message-only windows are invisible to FindWindowW
            hwnd = user32.FindWindowExW(hwnd_message(), None, self.window_class, self.window_title)
        return int(hwnd or 0)

    def send(self, hwnd: int, own_hwnd: int, dwdata: int, lpdata: bytes) -> int:
        """One WM_COPYDATA; returns the receiver's result (TRUE when it processed the frame)."""
        size = len(lpdata)
        buffer = ctypes.create_string_buffer(lpdata, size) if size else None
        cds = COPYDATASTRUCT()
        cds.dwData = dwdata
        cds.cbData = size
        cds.lpData = ctypes.addressof(buffer) if buffer is not None else None
        result = DWORD_PTR(0)
        ok = self.user32.SendMessageTimeoutW(
            hwnd,
            WM_COPYDATA,
            own_hwnd,
            ctypes.addressof(cds),
            SEND_FLAGS,
            self.timeout_ms,
            ctypes.pointer(result),
        )
        # `buffer` and `cds` are still referenced here: they stayed alive (and in place) for the whole call.
        del buffer, cds
        if ok:
            return int(result.value)
        error = self.get_last_error()
        gone = error == ERROR_INVALID_WINDOW_HANDLE or not self.user32.IsWindow(hwnd)
        timed_out = error == ERROR_TIMEOUT and not gone
        what = (
            "the window is gone"
            if gone
            else "timed out (receiver busy or hung)"
            if timed_out
            else f"error {error}"
        )
        raise SendFailed(
            f"SendMessageTimeoutW to window {hwnd:#x}: {what}",
            error=error,
            timed_out=timed_out,
            window_gone=gone,
        )

    def send_all(self, hwnd: int, own_hwnd: int, frames: list[OutFrame]) -> SendOutcome:
        """Send frames in order; stop at the first failure (the rest would fail the same way)."""
        outcome = SendOutcome(0, 0)
        for dwdata, lpdata in frames:
            try:
                if not self.send(hwnd, own_hwnd, dwdata, lpdata):
                    outcome.refused += 1
            except SendFailed as exc:
                outcome.failure = exc
                break
            outcome.sent += 1
        return outcome


# --- the gateway's own window ------------------------------------------------------------------------


class MessageWindow:
    """A hidden window that receives WM_COPYDATA replies; message-only unless `parent` says otherwise."""

    def __init__(
        self,
        user32: Any,
        kernel32: Any,
        on_copydata: ReplyCallback,
        *,
        max_cbdata: int = 1 << 20,
        title: str = "cnc-gateway COPYDATA",
        parent: int | None = None,
    ) -> None:
        self.user32 = user32
        self.kernel32 = kernel32
        self.on_copydata = on_copydata
        self.max_cbdata = max_cbdata
        self.title = title
        self.parent = hwnd_message() if parent is None else parent
        self.class_name = f"cnc-gateway.copydata.{os.getpid()}.{next(_class_ids)}"
        self.hwnd = 0
        self.rejected = 0
        # Kept on the instance: Windows calls it for as long as the window exists.
        self._wndproc = WNDPROC(self._window_procedure)
        self._hinstance: Any = None
        self._msg = MSG()

    def create(self) -> int:
        user32 = self.user32
        self._hinstance = self.kernel32.GetModuleHandleW(None)
        wc = WNDCLASSEXW()
        wc.cbSize = ctypes.sizeof(WNDCLASSEXW)
        wc.lpfnWndProc = self._wndproc
        wc.hInstance = self._hinstance
        wc.lpszClassName = self.class_name
        if not user32.RegisterClassExW(ctypes.pointer(wc)):
            raise SinkError(f"RegisterClassExW failed (error {last_error()})")
        hwnd = user32.CreateWindowExW(
            0, self.class_name, self.title, 0, 0, 0, 0, 0, self.parent, None, self._hinstance, None
        )
        if not hwnd:
            user32.UnregisterClassW(self.class_name, self._hinstance)
            raise SinkError(f"CreateWindowExW failed (error {last_error()})")
        self.hwnd = int(hwnd)
        # A receiver at a lower integrity level (UIPI) may still answer us.
        change_filter = getattr(user32, "ChangeWindowMessageFilterEx", None)
        if change_filter is not None:
            change_filter(self.hwnd, WM_COPYDATA, MSGFLT_ALLOW, None)
        return self.hwnd

    def destroy(self) -> None:
        if self.hwnd:
            self.user32.DestroyWindow(self.hwnd)
            self.user32.UnregisterClassW(self.class_name, self._hinstance)
            self.hwnd = 0

    def pump(self) -> None:
        """Dispatch what is waiting in this thread's queue (sent messages are delivered in here too)."""
        user32, msg = self.user32, self._msg
        pmsg = ctypes.pointer(msg)
        while user32.PeekMessageW(pmsg, None, 0, 0, PM_REMOVE):
            user32.TranslateMessage(pmsg)
            user32.DispatchMessageW(pmsg)

    def _window_procedure(self, hwnd: Any, message: int, wparam: int, lparam: int) -> int:
        if message != WM_COPYDATA:
            return int(self.user32.DefWindowProcW(hwnd, message, wparam, lparam) or 0)
        try:
            dwdata, data = read_copydatastruct(lparam, self.max_cbdata)
        except ValueError as exc:
            self.rejected += 1
            log.warning("copydata: WM_COPYDATA from window %#x ignored: %s", wparam or 0, exc)
            return 0
        try:
            self.on_copydata(int(wparam or 0), dwdata, data)
        except Exception:  # never let an exception cross back into Windows
            log.exception("copydata: handling a WM_COPYDATA reply failed")
            return 0
        return 1


# --- the thread that owns the window ---------------------------------------------------------------


class WindowThread:
    """Owns the message window; runs submitted calls (the sends) and dispatches incoming messages."""

    def __init__(
        self, user32: Any, kernel32: Any, window: MessageWindow, name: str = "copydata-window"
    ) -> None:
        self.user32 = user32
        self.kernel32 = kernel32
        self.window = window
        self.name = name
        self._jobs: queue.SimpleQueue[tuple[Callable[[], Any], concurrent.futures.Future[Any]]] = (
            queue.SimpleQueue()
        )
        self._event: Any = None
        self._stopping = False
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None

    @property
    def hwnd(self) -> int:
        return self.window.hwnd

    def start(self, timeout: float = 10.0) -> None:
        """Start the thread and wait until its window exists (raises what creating it raised)."""
        self._event = self.kernel32.CreateEventW(None, False, False, None)
        if not self._event:
            raise SinkError("CreateEventW failed")
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise SinkError("the COPYDATA window thread did not start")
        if self._error is not None:
            raise self._error

    def submit(self, call: Callable[[], Any]) -> concurrent.futures.Future[Any]:
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        if self._stopping:
            future.set_exception(RuntimeError("the COPYDATA window thread is stopping"))
            return future
        self._jobs.put((call, future))
        self.kernel32.SetEvent(self._event)
        return future

    def stop(self, timeout: float = 5.0) -> None:
        self._stopping = True
        if self._event:
            self.kernel32.SetEvent(self._event)
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
        if self._event:
            self.kernel32.CloseHandle(self._event)
            self._event = None

    def _run(self) -> None:
        window = self.window
        try:
            window.create()
        except BaseException as exc:  # noqa: BLE001 - re-raised by start() in the caller's thread
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        handles = (HANDLE * 1)(self._event)
        try:
            while not self._stopping:
                woke = self.user32.MsgWaitForMultipleObjects(1, handles, False, WAKE_EVERY_MS, QS_ALLINPUT)
                window.pump()
                self._run_jobs()
                if woke == WAIT_FAILED:
                    log.error("copydata: MsgWaitForMultipleObjects failed (error %d)", last_error())
                    break
        finally:
            self._cancel_jobs()
            window.destroy()

    def _run_jobs(self) -> None:
        while True:
            try:
                call, future = self._jobs.get_nowait()
            except queue.Empty:
                return
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(call())
            except BaseException as exc:  # noqa: BLE001 - handed to the waiting coroutine
                future.set_exception(exc)

    def _cancel_jobs(self) -> None:
        while True:
            try:
                _, future = self._jobs.get_nowait()
            except queue.Empty:
                return
            future.cancel()


# --- the asyncio side ------------------------------------------------------------------------------


class Win32Transport:
    """Frames to the receiver's window; replies from it to the emitter's feedback."""

    def __init__(
        self,
        emitter: TransportPort,
        api: tuple[Any, Any] | None = None,
        get_last_error: Callable[[], int] = last_error,
    ) -> None:
        self.emitter = emitter
        self.target = emitter.target
        self.api = api
        self.get_last_error = get_last_error
        self.hwnd = 0  # the receiver's window, once found
        self.timeouts = 0
        self.refused = 0
        self.replies_dropped = 0
        self.thread: WindowThread | None = None
        self._replies: asyncio.Queue[tuple[int, int, bytes]] = asyncio.Queue(REPLY_QUEUE)

    def describe(self) -> str:
        return self.target.describe()

    async def run(self) -> None:
        user32, kernel32 = self.api if self.api is not None else load_api()
        loop = asyncio.get_running_loop()
        target = self.target

        def on_copydata(wparam: int, dwdata: int, data: bytes) -> None:  # on the window thread
            loop.call_soon_threadsafe(self._reply, wparam, dwdata, data)

        window = MessageWindow(user32, kernel32, on_copydata, max_cbdata=self.emitter.layout.max_cbdata)
        thread = WindowThread(user32, kernel32, window, name=f"copydata:{self.emitter.name}:window")
        await asyncio.to_thread(thread.start)
        self.thread = thread
        sender = CopydataSender(
            user32, window_class=target.window_class, window_title=target.window_title,
            timeout_ms=int(target.timeout * 1000), get_last_error=self.get_last_error,
        )  # fmt: skip
        log.info("copydata %s: replies go to window %#x", self.emitter.name, thread.hwnd)
        try:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(self._replies_worker(), name=f"copydata:{self.emitter.name}:replies")
                await self._deliver(thread, sender)
        finally:
            self.thread = None
            await asyncio.to_thread(thread.stop)

    async def _deliver(self, thread: WindowThread, sender: CopydataSender) -> None:
        emitter = self.emitter
        backoff = Backoff.of(self.target.backoff)
        absent = OutageLog(log)  # the receiver's window: said once while it is missing, and when found
        while True:
            hwnd = await asyncio.wrap_future(thread.submit(sender.find))
            if not hwnd:
                emitter.set_state("waiting for the window")
                absent.failed("no window", "copydata %s: no window %s yet; looking again with backoff",
                              emitter.name, self.target.describe().removeprefix("win32 window "))  # fmt: skip
                await asyncio.sleep(backoff.next())
                continue
            backoff.reset()
            self.hwnd = hwnd
            absent.recovered("copydata %s: sending to window %#x", emitter.name, hwnd)
            emitter.set_state(f"sending to window {hwnd:#x}")
            channel = emitter.open_channel(f"window {hwnd:#x}")
            try:
                while True:
                    frames = await channel.next_frames()
                    outcome: SendOutcome = await asyncio.wrap_future(
                        thread.submit(lambda f=frames, h=hwnd: sender.send_all(h, thread.hwnd, f))  # type: ignore[misc]
                    )
                    channel.sent += outcome.sent
                    self.refused += outcome.refused
                    failure = outcome.failure
                    if failure is None:
                        backoff.reset()
                        continue
                    if failure.window_gone:
                        log.warning("copydata %s: %s; looking for it again", emitter.name, failure)
                        break
                    # A hung receiver fails at once (SMTO_ABORTIFHUNG): wait before trying it again.
                    self.timeouts += 1
                    delay = backoff.next()
                    emitter.throttle.log(
                        f"copydata {emitter.name} timeouts", logging.WARNING,
                        "copydata %s: %s; trying again in %.1f s, starting from a snapshot",
                        emitter.name, failure, delay,
                    )  # fmt: skip
                    channel.request_snapshot()
                    await asyncio.sleep(delay)
            finally:
                emitter.close_channel(channel)
                self.hwnd = 0

    def _reply(self, wparam: int, dwdata: int, data: bytes) -> None:
        try:
            self._replies.put_nowait((wparam, dwdata, data))
        except asyncio.QueueFull:
            self.replies_dropped += 1

    async def _replies_worker(self) -> None:
        emitter = self.emitter
        while True:
            wparam, dwdata, data = await self._replies.get()
            peer = f"window {wparam:#x}"
            try:
                frame = decode_lpdata(dwdata, data, emitter.layout)
            except CopydataError as exc:
                emitter.throttle.log(
                    f"copydata {emitter.name} malformed", logging.WARNING,
                    "copydata %s: WM_COPYDATA from %s ignored: malformed frame (%s): %s",
                    emitter.name, peer, exc.kind, exc,
                )  # fmt: skip
                continue
            await emitter.on_frame(frame, peer)
