"""The WM_COPYDATA transport: struct layout and signatures on every system, the send and reply paths
against a stand-in for user32 (fake_win32.py), and the real thing on Windows."""

from __future__ import annotations

import asyncio
import ctypes
import subprocess
import sys
import uuid
from collections.abc import AsyncIterator
from typing import Any

import pytest

from gateway.codecs.copydata import (
    WM_COPYDATA,
    copydatastruct_layout,
    decode_lpdata,
    pack_copydatastruct,
)
from gateway.errors import SinkError
from gateway.sinks.copydata import win32_api as api
from gateway.sinks.copydata.emitter import Emitter
from gateway.sinks.copydata.win32 import (
    CopydataSender,
    MessageWindow,
    SendFailed,
    Win32Transport,
    WindowThread,
    load_api,
    read_copydatastruct,
)
from tests.unit.sinks.copydata.fake_win32 import ERROR_TIMEOUT, FakeKernel32, FakeUser32
from tests.unit.sinks.copydata.helpers import copydata_sink, ingest, mapping
from tests.waiting import wait_until

# --- layout and signatures: the same numbers on every host ---------------------------------------


@pytest.mark.parametrize("pointer_size", [4, 8])
def test_copydatastruct_layout_for_both_pointer_sizes(pointer_size: int) -> None:
    struct_type = api.copydatastruct_type(pointer_size)
    expected = copydatastruct_layout(pointer_size)
    assert ctypes.sizeof(struct_type) == expected.size == {4: 12, 8: 24}[pointer_size]
    assert struct_type.dwData.offset == expected.offset_dwdata == 0  # type: ignore[attr-defined]
    assert struct_type.cbData.offset == expected.offset_cbdata  # type: ignore[attr-defined]
    assert struct_type.lpData.offset == expected.offset_lpdata  # type: ignore[attr-defined]
    value = struct_type(2, 40, 0x1234_5678)
    assert bytes(value) == pack_copydatastruct(pointer_size, 2, 40, 0x1234_5678)


def test_64_bit_struct_is_24_bytes_with_cbdata_at_8_and_lpdata_at_16() -> None:
    struct_type = api.copydatastruct_type(8)
    assert (ctypes.sizeof(struct_type), struct_type.cbData.offset, struct_type.lpData.offset) == (24, 8, 16)  # type: ignore[attr-defined]


def test_the_native_struct_is_pointer_sized() -> None:
    native = api.COPYDATASTRUCT
    layout = copydatastruct_layout(ctypes.sizeof(ctypes.c_void_p))
    assert ctypes.sizeof(native) == layout.size
    assert native.lpData.offset == layout.offset_lpdata  # type: ignore[attr-defined]
    assert ctypes.sizeof(api.ULONG_PTR) == ctypes.sizeof(ctypes.c_void_p)


def test_windows_integer_types_have_windows_sizes_on_any_host() -> None:
    pointer = ctypes.sizeof(ctypes.c_void_p)
    assert ctypes.sizeof(api.DWORD) == ctypes.sizeof(api.UINT) == ctypes.sizeof(api.BOOL) == 4
    for pointer_sized in (api.WPARAM, api.LPARAM, api.LRESULT, api.DWORD_PTR, api.HWND, api.HANDLE):
        assert ctypes.sizeof(pointer_sized) == pointer, pointer_sized
    assert ctypes.sizeof(api.WNDCLASSEXW) == (80 if pointer == 8 else 48)


def test_send_message_timeout_has_explicit_pointer_sized_arguments() -> None:
    restype, argtypes = api.USER32["SendMessageTimeoutW"]
    assert restype is api.LRESULT
    assert argtypes[:6] == (api.HWND, api.UINT, api.WPARAM, api.LPARAM, api.UINT, api.UINT)
    assert argtypes[6]._type_ is api.DWORD_PTR  # lpdwResult: PDWORD_PTR
    assert api.USER32["FindWindowW"] == (api.HWND, (api.LPCWSTR, api.LPCWSTR))
    assert api.SEND_FLAGS & api.SMTO_ABORTIFHUNG and not api.SEND_FLAGS & api.SMTO_BLOCK


def test_bind_sets_restype_and_argtypes_of_every_function() -> None:
    class Function:
        restype: Any = None
        argtypes: Any = None

    class Dll:
        def __getattr__(self, name: str) -> Function:
            function = Function()
            setattr(self, name, function)
            return function

    dll = api.bind(Dll(), api.USER32)
    for name, (restype, argtypes) in api.USER32.items():
        function = getattr(dll, name)
        assert function.restype is restype and function.argtypes == list(argtypes), name


def test_the_module_imports_without_touching_windll() -> None:
    code = (
        "import ctypes\n"
        "class Refuse:\n"
        "    def __getattr__(self, name): raise AssertionError('windll touched at import')\n"
        "    def __call__(self, *a, **k): raise AssertionError('WinDLL called at import')\n"
        "ctypes.windll = Refuse(); ctypes.WinDLL = Refuse()\n"
        "import gateway.sinks.copydata.win32, gateway.sinks.copydata.win32_api\n"
        "print('ok')\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


@pytest.mark.skipif(sys.platform == "win32", reason="on Windows the real user32 loads")
def test_loading_user32_elsewhere_is_a_clear_error() -> None:
    with pytest.raises(SinkError, match="WM_COPYDATA needs Windows"):
        load_api()


# --- the send path against the stand-in ------------------------------------------------------------


def os_pair() -> tuple[FakeUser32, FakeKernel32]:
    kernel32 = FakeKernel32()
    return FakeUser32(kernel32), kernel32


def test_find_window_by_class_and_title_then_among_message_only_windows() -> None:
    user32, _ = os_pair()
    sender = CopydataSender(
        user32,
        window_class="NestWnd",
        window_title=None,
        timeout_ms=500,
        get_last_error=user32.get_last_error,
    )
    assert sender.find() == 0x2000
    assert ("FindWindowW", "NestWnd", None) in user32.calls
    user32.receiver_exists = False
    assert sender.find() == 0
    assert user32.calls[-1] == ("FindWindowExW", api.hwnd_message(), None, "NestWnd", None)


def test_send_passes_a_struct_and_buffer_the_receiver_can_read() -> None:
    user32, _ = os_pair()
    sender = CopydataSender(
        user32,
        window_class=None,
        window_title="Nesting",
        timeout_ms=1500,
        get_last_error=user32.get_last_error,
    )
    lpdata = bytes.fromhex("0100 0800 00000000004a9340")
    assert sender.send(0x2000, 0x3000, 2, lpdata) == 1
    (got,) = user32.received
    assert (got.dwdata, got.data, got.cbdata_field, got.wparam) == (2, lpdata, len(lpdata), 0x3000)
    assert got.flags == api.SMTO_ABORTIFHUNG | api.SMTO_ERRORONEXIT and got.timeout_ms == 1500


def test_a_receiver_that_returns_false_is_counted_not_retried() -> None:
    user32, _ = os_pair()
    user32.answer = 0
    sender = CopydataSender(
        user32,
        window_class="NestWnd",
        window_title=None,
        timeout_ms=100,
        get_last_error=user32.get_last_error,
    )
    outcome = sender.send_all(0x2000, 0, [(1, b"\x01\x00\x01\x00\x01"), (1, b"\x01\x00\x01\x00\x00")])
    assert (outcome.sent, outcome.refused, outcome.failure) == (2, 2, None)


def test_a_timeout_and_a_vanished_window_are_told_apart() -> None:
    user32, _ = os_pair()
    sender = CopydataSender(
        user32,
        window_class="NestWnd",
        window_title=None,
        timeout_ms=100,
        get_last_error=user32.get_last_error,
    )
    user32.fail_with = ERROR_TIMEOUT
    with pytest.raises(SendFailed) as info:
        sender.send(0x2000, 0, 1, b"\x01\x00\x00\x00")
    assert info.value.timed_out and not info.value.window_gone
    user32.fail_with = None
    user32.receiver_exists = False
    outcome = sender.send_all(0x2000, 0, [(1, b"\x01\x00\x00\x00"), (1, b"\x02\x00\x00\x00")])
    assert outcome.sent == 0 and outcome.failure is not None and outcome.failure.window_gone


def test_reading_a_copydatastruct_is_bounded() -> None:
    data = ctypes.create_string_buffer(b"\x05\x00\x04\x00\x2a\x00\x00\x00", 8)
    cds = api.COPYDATASTRUCT(1, 8, ctypes.addressof(data))
    assert read_copydatastruct(ctypes.addressof(cds), 1024) == (1, data.raw)
    with pytest.raises(ValueError, match="over max_cbdata 4"):
        read_copydatastruct(ctypes.addressof(cds), 4)
    empty = api.COPYDATASTRUCT(1, 8, None)
    with pytest.raises(ValueError, match="lpData is NULL"):
        read_copydatastruct(ctypes.addressof(empty), 1024)


def test_the_message_window_is_message_only_and_decodes_replies() -> None:
    user32, kernel32 = os_pair()
    got: list[tuple[int, int, bytes]] = []
    window = MessageWindow(user32, kernel32, lambda w, d, b: got.append((w, d, b)), max_cbdata=64)
    hwnd = window.create()
    procedure, parent = user32.windows[hwnd]
    assert parent == api.hwnd_message()
    assert ("ChangeWindowMessageFilterEx", hwnd, WM_COPYDATA, api.MSGFLT_ALLOW) in user32.calls
    user32._send_reply(hwnd, 1, bytes.fromhex("0600 0200 3200"))
    assert got == [(user32.receiver_hwnd, 1, bytes.fromhex("0600 0200 3200"))]
    assert user32.replies_sent[-1][2] == 1  # TRUE: processed
    user32._send_reply(hwnd, 2, b"x" * 65)  # over max_cbdata: refused, nothing copied
    assert user32.replies_sent[-1][2] == 0 and window.rejected == 1 and len(got) == 1
    assert procedure(hwnd, 0x0001, 0, 0) == 0 and ("DefWindowProcW", 0x0001) in user32.calls
    window.destroy()
    assert hwnd not in user32.windows


def test_the_window_thread_runs_sends_and_stops() -> None:
    user32, kernel32 = os_pair()
    window = MessageWindow(user32, kernel32, lambda *a: None)
    thread = WindowThread(user32, kernel32, window)
    thread.start()
    try:
        assert thread.hwnd in user32.windows
        assert thread.submit(lambda: 6 * 7).result(timeout=5) == 42
        with pytest.raises(ZeroDivisionError):
            thread.submit(lambda: 1 / 0).result(timeout=5)
    finally:
        thread.stop()
    assert thread.hwnd == 0 and not user32.windows


# --- the whole transport, with the stand-in --------------------------------------------------------


@pytest.fixture
async def win32_target(
    request: pytest.FixtureRequest,
) -> AsyncIterator[tuple[Emitter, Win32Transport, FakeUser32]]:
    settings = {"name": "nest", "transport": "win32", "window_class": "NestWnd", "max_rate": None,
                "backoff": {"initial": 0.02, "max": 0.05}, **getattr(request, "param", {})}  # fmt: skip
    sink = copydata_sink(mapping(settings))
    emitter = sink.emitters[0]
    user32, kernel32 = os_pair()
    emitter.transport = transport = Win32Transport(
        emitter, api=(user32, kernel32), get_last_error=user32.get_last_error
    )
    emitter._sub = emitter.machine.tree.hub.subscribe("copydata:test")
    task = asyncio.create_task(emitter.run())
    try:
        yield emitter, transport, user32
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await emitter.__aexit__(None, None, None)


def frames_of(emitter: Emitter, user32: FakeUser32) -> list[dict[str, Any]]:
    out = []
    for got in list(user32.received):
        frame = decode_lpdata(got.dwdata, got.data, emitter.layout)
        out.append({r.variable.name: r.value for r in emitter.encoder.table.decode(frame, emitter.layout)})
    return out


async def test_frames_reach_the_window_starting_with_a_snapshot(win32_target: Any) -> None:
    emitter, transport, user32 = win32_target
    m = emitter.machine
    ingest(m, "Program/Block", 3)
    await wait_until(lambda: user32.received, message="the first WM_COPYDATA")
    assert user32.received[0].dwdata == 2 and frames_of(emitter, user32)[0] == {"Program/Block": 3}
    assert user32.received[0].wparam == transport.thread.hwnd  # where replies go
    ingest(m, "Axes/X/Position", 12.5)
    await wait_until(lambda: {"Axes/X/Position": 12.5} in frames_of(emitter, user32), message="the change")
    assert emitter.describe().startswith("nest: win32 window class 'NestWnd' sending to window 0x2000")


async def test_replies_to_the_gateway_window_become_feedback(win32_target: Any) -> None:
    emitter, _transport, user32 = win32_target
    events = emitter.machine.tree.events.subscribe("test")
    user32.reply = lambda dwdata, data: (1, bytes.fromhex("0500 0400 07000000"))  # "I am at block 7"
    ingest(emitter.machine, "Program/Block", 3)
    await wait_until(lambda: events.take() or None, message="the feedback event")  # type: ignore[arg-type]
    status = emitter.machine.nodes["Status/CopydataFeedback"].sample.value
    assert (
        '"path":"Program/Block","value":7' in status
        and f'"peer":"window {user32.receiver_hwnd:#x}"' in status
    )


async def test_a_vanished_window_is_found_again_and_gets_a_new_snapshot(win32_target: Any) -> None:
    emitter, _transport, user32 = win32_target
    ingest(emitter.machine, "Program/Block", 1)
    await wait_until(lambda: user32.received, message="the first frame")
    user32.receiver_exists = False
    ingest(emitter.machine, "Program/Block", 2)
    await wait_until(
        lambda: "waiting for the window" in emitter.describe(), message="the transport to look again"
    )
    before = len(user32.received)
    user32.receiver_exists = True
    await wait_until(lambda: len(user32.received) > before, message="a frame to the window that is back")
    assert user32.received[before].dwdata == 2 and frames_of(emitter, user32)[before] == {"Program/Block": 2}


async def test_a_timed_out_frame_is_followed_by_a_snapshot(win32_target: Any) -> None:
    emitter, transport, user32 = win32_target
    ingest(emitter.machine, "Program/Block", 1)
    await wait_until(lambda: user32.received, message="the first frame")
    user32.fail_with = ERROR_TIMEOUT
    ingest(emitter.machine, "Program/Block", 2)
    await wait_until(lambda: transport.timeouts, message="a timeout")
    ingest(emitter.machine, "Axes/X/Position", 1.5)
    user32.fail_with = None
    await wait_until(lambda: len(user32.received) >= 2, message="frames again")
    # The change that timed out is not lost: a snapshot (built after the timeout) carries it.
    assert user32.received[1].dwdata == 2 and frames_of(emitter, user32)[1]["Program/Block"] == 2
    await wait_until(
        lambda: frames_of(emitter, user32)[-1].get("Axes/X/Position") == 1.5, message="the next change"
    )


# --- the real thing -----------------------------------------------------------------------------------


@pytest.mark.skipif(
    sys.platform != "win32", reason="sends real WM_COPYDATA between two windows: Windows only"
)
async def test_real_wm_copydata_round_trip_on_windows() -> None:
    """A receiver window in this process (its own thread), found by title, gets frames and answers."""
    user32, kernel32 = load_api()
    title = f"cnc-gateway test receiver {uuid.uuid4().hex[:8]}"
    received: list[tuple[int, bytes]] = []
    answer = CopydataSender(user32, window_class=None, window_title=title, timeout_ms=2000)

    def on_copydata(wparam: int, dwdata: int, data: bytes) -> None:  # the receiver's window procedure
        received.append((dwdata, data))
        if wparam:
            answer.send(wparam, receiver.hwnd, 1, bytes.fromhex("0500 0400 07000000"))

    receiver = WindowThread(
        user32, kernel32, MessageWindow(user32, kernel32, on_copydata, title=title, parent=0)
    )
    receiver.start()
    target = {"name": "nest", "transport": "win32", "window_title": title, "max_rate": None}
    sink = copydata_sink(mapping(target))
    emitter = sink.emitters[0]
    events = emitter.machine.tree.events.subscribe("test")
    async with sink:
        task = asyncio.create_task(sink.run())
        try:
            ingest(emitter.machine, "Program/Block", 42)
            await wait_until(lambda: received, timeout=15, message="a WM_COPYDATA at the receiver")
            dwdata, data = received[0]
            frame = decode_lpdata(dwdata, data, emitter.layout)
            assert {
                r.variable.name: r.value for r in emitter.encoder.table.decode(frame, emitter.layout)
            } == {"Program/Block": 42}
            await wait_until(lambda: events.take() or None, timeout=15, message="the reply as feedback")  # type: ignore[arg-type]
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            receiver.stop()
