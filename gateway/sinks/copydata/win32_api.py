"""The Win32 declarations the WM_COPYDATA sender needs, as plain ctypes: importable on every system.

Nothing here loads a DLL or touches `ctypes.windll`; `bind()` applies the
signatures to a DLL (or to a stand-in in tests). The types are spelled out with
fixed-width ctypes rather than taken from `ctypes.wintypes`, whose DWORD is a
C `unsigned long` (8 bytes on Linux): the sizes below are Windows' own on any
host, so tests on Linux check the same layout that Windows uses. Pointer-sized
types (WPARAM, LPARAM, LRESULT, ULONG_PTR, handles) follow the running
interpreter, as on Windows, where a 32-bit and a 64-bit Python differ.
"""

from __future__ import annotations

import ctypes
from typing import Any

POINTER_SIZE = ctypes.sizeof(ctypes.c_void_p)

BOOL = ctypes.c_int32
INT = ctypes.c_int32
UINT = ctypes.c_uint32
DWORD = ctypes.c_uint32
ATOM = ctypes.c_uint16
WPARAM = ctypes.c_size_t  # UINT_PTR
LPARAM = ctypes.c_ssize_t  # LONG_PTR
LRESULT = ctypes.c_ssize_t  # LONG_PTR
ULONG_PTR = ctypes.c_size_t
DWORD_PTR = ctypes.c_size_t
HANDLE = ctypes.c_void_p
HWND = ctypes.c_void_p
HINSTANCE = ctypes.c_void_p
HMODULE = ctypes.c_void_p
HICON = ctypes.c_void_p
HCURSOR = ctypes.c_void_p
HBRUSH = ctypes.c_void_p
HMENU = ctypes.c_void_p
LPVOID = ctypes.c_void_p
LPCWSTR = ctypes.c_wchar_p

# Windows calls window procedures with the stdcall convention (the same as cdecl on x64).
FUNCTYPE: Any = getattr(ctypes, "WINFUNCTYPE", ctypes.CFUNCTYPE)
WNDPROC = FUNCTYPE(LRESULT, HWND, UINT, WPARAM, LPARAM)

# --- constants ------------------------------------------------------------------------------------

WM_CLOSE = 0x0010
SMTO_NORMAL = 0x0000
SMTO_BLOCK = 0x0001  # not used: it would stop our thread from taking the receiver's synchronous reply
SMTO_ABORTIFHUNG = 0x0002
SMTO_ERRORONEXIT = 0x0020
HWND_MESSAGE = -3  # parent of a message-only window
PM_REMOVE = 0x0001
QS_ALLINPUT = 0x04FF
WAIT_OBJECT_0 = 0x00000000
WAIT_TIMEOUT = 0x00000102
WAIT_FAILED = 0xFFFFFFFF
MSGFLT_ALLOW = 1
ERROR_INVALID_WINDOW_HANDLE = 1400
ERROR_TIMEOUT = 1460
SEND_FLAGS = SMTO_ABORTIFHUNG | SMTO_ERRORONEXIT


# --- structures -----------------------------------------------------------------------------------

_FIXED = {4: ctypes.c_uint32, 8: ctypes.c_uint64}


def copydatastruct_type(pointer_size: int | None = None) -> type[ctypes.Structure]:
    """`COPYDATASTRUCT {ULONG_PTR dwData; DWORD cbData; PVOID lpData;}` for a pointer size.

    The native one (None, or this interpreter's size) uses real pointer types, to
    be passed to SendMessageTimeoutW. The other size is built from fixed-width
    integers with the same natural alignment, so that both layouts (24 bytes on
    64-bit, 12 on 32-bit) can be checked on any host.
    """
    if pointer_size is None or pointer_size == POINTER_SIZE:
        return COPYDATASTRUCT
    if pointer_size not in _FIXED:
        raise ValueError(f"pointer_size must be 4 or 8, got {pointer_size!r}")
    word = _FIXED[pointer_size]

    class _CopyDataStruct(ctypes.Structure):
        _fields_ = [("dwData", word), ("cbData", DWORD), ("lpData", word)]

    _CopyDataStruct.__name__ = f"COPYDATASTRUCT{8 * pointer_size}"
    return _CopyDataStruct


class COPYDATASTRUCT(ctypes.Structure):
    _fields_ = [("dwData", ULONG_PTR), ("cbData", DWORD), ("lpData", ctypes.c_void_p)]


class POINT(ctypes.Structure):
    _fields_ = [("x", ctypes.c_int32), ("y", ctypes.c_int32)]


class MSG(ctypes.Structure):
    _fields_ = [
        ("hwnd", HWND),
        ("message", UINT),
        ("wParam", WPARAM),
        ("lParam", LPARAM),
        ("time", DWORD),
        ("pt", POINT),
    ]


class WNDCLASSEXW(ctypes.Structure):
    _fields_ = [
        ("cbSize", UINT),
        ("style", UINT),
        ("lpfnWndProc", WNDPROC),
        ("cbClsExtra", INT),
        ("cbWndExtra", INT),
        ("hInstance", HINSTANCE),
        ("hIcon", HICON),
        ("hCursor", HCURSOR),
        ("hbrBackground", HBRUSH),
        ("lpszMenuName", LPCWSTR),
        ("lpszClassName", LPCWSTR),
        ("hIconSm", HICON),
    ]


# --- function signatures: name -> (restype, argtypes) ----------------------------------------------

Signature = tuple[Any, tuple[Any, ...]]

USER32: dict[str, Signature] = {
    "FindWindowW": (HWND, (LPCWSTR, LPCWSTR)),
    "FindWindowExW": (HWND, (HWND, HWND, LPCWSTR, LPCWSTR)),
    "SendMessageTimeoutW": (LRESULT, (HWND, UINT, WPARAM, LPARAM, UINT, UINT, ctypes.POINTER(DWORD_PTR))),
    "IsWindow": (BOOL, (HWND,)),
    "RegisterClassExW": (ATOM, (ctypes.POINTER(WNDCLASSEXW),)),
    "UnregisterClassW": (BOOL, (LPCWSTR, HINSTANCE)),
    "CreateWindowExW": (
        HWND,
        (DWORD, LPCWSTR, LPCWSTR, DWORD, INT, INT, INT, INT, HWND, HMENU, HINSTANCE, LPVOID),
    ),
    "DestroyWindow": (BOOL, (HWND,)),
    "DefWindowProcW": (LRESULT, (HWND, UINT, WPARAM, LPARAM)),
    "PeekMessageW": (BOOL, (ctypes.POINTER(MSG), HWND, UINT, UINT, UINT)),
    "TranslateMessage": (BOOL, (ctypes.POINTER(MSG),)),
    "DispatchMessageW": (LRESULT, (ctypes.POINTER(MSG),)),
    "MsgWaitForMultipleObjects": (DWORD, (DWORD, ctypes.POINTER(HANDLE), BOOL, DWORD, DWORD)),
    "ChangeWindowMessageFilterEx": (BOOL, (HWND, UINT, DWORD, LPVOID)),
}

KERNEL32: dict[str, Signature] = {
    "GetModuleHandleW": (HMODULE, (LPCWSTR,)),
    "CreateEventW": (HANDLE, (LPVOID, BOOL, BOOL, LPCWSTR)),
    "SetEvent": (BOOL, (HANDLE,)),
    "CloseHandle": (BOOL, (HANDLE,)),
}


def bind(dll: Any, signatures: dict[str, Signature]) -> Any:
    """Give every function its explicit restype and argtypes: without them ctypes passes
    handles and pointers as C ints, truncated to 32 bits on 64-bit Windows."""
    for name, (restype, argtypes) in signatures.items():
        function = getattr(dll, name)
        function.restype = restype
        function.argtypes = list(argtypes)
    return dll


def hwnd_message() -> int:
    """HWND_MESSAGE, (HWND)-3, as the unsigned pointer value ctypes passes."""
    return HWND_MESSAGE & ((1 << (8 * POINTER_SIZE)) - 1)
