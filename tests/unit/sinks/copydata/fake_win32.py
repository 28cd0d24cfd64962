"""A stand-in for user32 and kernel32: the operating system's side, not our code.

It holds one receiver window (the nesting software), finds it by class and
title like FindWindowW, and takes WM_COPYDATA the way Windows hands it to the
receiver: by reading the COPYDATASTRUCT and the bytes at lpData through
ctypes, from the addresses the sender passed. It can answer each frame
synchronously with a WM_COPYDATA of its own to the window in wParam, calling
that window's procedure through its ctypes callback, as a real receiver's
SendMessage would. Events are threading.Events, so the window thread really
sleeps and wakes.
"""

from __future__ import annotations

import ctypes
import itertools
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from gateway.codecs.copydata import WM_COPYDATA
from gateway.sinks.copydata.win32_api import COPYDATASTRUCT, WAIT_OBJECT_0, WAIT_TIMEOUT, WNDCLASSEXW

ERROR_INVALID_WINDOW_HANDLE = 1400
ERROR_TIMEOUT = 1460


class FakeKernel32:
    def __init__(self) -> None:
        self.events: dict[int, threading.Event] = {}
        self._handles = itertools.count(0x100)

    def GetModuleHandleW(self, name: Any) -> int:
        return 0x400000

    def CreateEventW(self, attributes: Any, manual_reset: bool, initial: bool, name: Any) -> int:
        handle = next(self._handles)
        self.events[handle] = threading.Event()
        return handle

    def SetEvent(self, handle: int) -> int:
        self.events[handle].set()
        return 1

    def CloseHandle(self, handle: int) -> int:
        self.events.pop(handle, None)
        return 1


@dataclass
class Received:
    hwnd: int
    wparam: int
    dwdata: int
    data: bytes
    flags: int
    timeout_ms: int
    cbdata_field: int  # cbData as read from the struct in memory


ReplyMaker = Callable[[int, bytes], "tuple[int, bytes] | None"]


@dataclass
class FakeUser32:
    kernel32: FakeKernel32
    window_class: str = "NestWnd"
    window_title: str = "Nesting"
    receiver_hwnd: int = 0x2000
    receiver_exists: bool = True
    answer: int = 1  # what the receiver's window procedure returns
    fail_with: int | None = None  # make SendMessageTimeoutW fail with this error code
    reply: ReplyMaker | None = None  # the receiver's synchronous answer to a frame
    received: list[Received] = field(default_factory=list)
    calls: list[tuple[Any, ...]] = field(default_factory=list)
    classes: dict[str, Any] = field(default_factory=dict)
    windows: dict[int, tuple[Any, int]] = field(
        default_factory=dict
    )  # our windows: hwnd -> (procedure, parent)
    replies_sent: list[tuple[int, bytes, int]] = field(default_factory=list)
    last_error: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    _hwnds: Any = field(default_factory=lambda: itertools.count(0x3000))

    def get_last_error(self) -> int:
        return self.last_error

    # --- finding ------------------------------------------------------------------------------

    def FindWindowW(self, cls: str | None, title: str | None) -> int | None:
        self.calls.append(("FindWindowW", cls, title))
        if not self.receiver_exists:
            return None
        if cls is not None and cls != self.window_class:
            return None
        if title is not None and title != self.window_title:
            return None
        return self.receiver_hwnd

    def FindWindowExW(self, parent: Any, after: Any, cls: str | None, title: str | None) -> int | None:
        self.calls.append(("FindWindowExW", parent, after, cls, title))
        return None

    def IsWindow(self, hwnd: int) -> int:
        return int((hwnd == self.receiver_hwnd and self.receiver_exists) or hwnd in self.windows)

    # --- sending ------------------------------------------------------------------------------

    def SendMessageTimeoutW(
        self, hwnd: int, msg: int, wparam: int, lparam: int, flags: int, timeout_ms: int, presult: Any
    ) -> int:
        assert isinstance(lparam, int), "lParam must be the struct's address, as a pointer-sized integer"
        self.calls.append(("SendMessageTimeoutW", hwnd, msg, wparam, flags, timeout_ms))
        if self.fail_with is not None:
            self.last_error = self.fail_with
            return 0
        if hwnd != self.receiver_hwnd or not self.receiver_exists:
            self.last_error = ERROR_INVALID_WINDOW_HANDLE
            return 0
        assert msg == WM_COPYDATA
        cds = COPYDATASTRUCT.from_address(lparam)
        data = ctypes.string_at(cds.lpData, cds.cbData) if cds.cbData else b""
        with self.lock:
            self.received.append(
                Received(hwnd, wparam, int(cds.dwData), data, flags, timeout_ms, int(cds.cbData))
            )
        if self.reply is not None and wparam in self.windows:
            answer = self.reply(int(cds.dwData), data)
            if answer is not None:
                self._send_reply(wparam, *answer)
        presult.contents.value = self.answer
        return 1

    def _send_reply(self, target: int, dwdata: int, data: bytes) -> None:
        """What the receiver's SendMessage(wParam, WM_COPYDATA, …) does: our procedure runs, right now."""
        procedure, _ = self.windows[target]
        buffer = ctypes.create_string_buffer(data, len(data))
        cds = COPYDATASTRUCT(dwdata, len(data), ctypes.addressof(buffer))
        result = procedure(target, WM_COPYDATA, self.receiver_hwnd, ctypes.addressof(cds))
        self.replies_sent.append((dwdata, data, result))

    # --- our window ---------------------------------------------------------------------------

    def RegisterClassExW(self, pwc: Any) -> int:
        wc = pwc.contents
        assert wc.cbSize == ctypes.sizeof(WNDCLASSEXW)
        self.classes[wc.lpszClassName] = wc.lpfnWndProc
        return 1

    def UnregisterClassW(self, name: str, instance: Any) -> int:
        return int(self.classes.pop(name, None) is not None)

    def CreateWindowExW(self, ex: int, cls: str, title: str, style: int, x: int, y: int, w: int, h: int,
                        parent: Any, menu: Any, instance: Any, param: Any) -> int:  # fmt: skip
        hwnd = next(self._hwnds)
        self.windows[hwnd] = (self.classes[cls], parent)
        return hwnd

    def DestroyWindow(self, hwnd: int) -> int:
        return int(self.windows.pop(hwnd, None) is not None)

    def DefWindowProcW(self, hwnd: Any, msg: int, wparam: int, lparam: int) -> int:
        self.calls.append(("DefWindowProcW", msg))
        return 0

    def ChangeWindowMessageFilterEx(self, hwnd: int, msg: int, action: int, info: Any) -> int:
        self.calls.append(("ChangeWindowMessageFilterEx", hwnd, msg, action))
        return 1

    # --- the message loop ---------------------------------------------------------------------

    def MsgWaitForMultipleObjects(self, count: int, handles: Any, wait_all: bool, ms: int, mask: int) -> int:
        event = self.kernel32.events[handles[0]]
        woke = event.wait(ms / 1000)
        event.clear()  # an auto-reset event
        return WAIT_OBJECT_0 if woke else WAIT_TIMEOUT

    def PeekMessageW(self, msg: Any, hwnd: Any, low: int, high: int, remove: int) -> int:
        return 0

    def TranslateMessage(self, msg: Any) -> int:
        return 0

    def DispatchMessageW(self, msg: Any) -> int:
        return 0
