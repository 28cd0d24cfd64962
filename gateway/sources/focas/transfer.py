"""Programs in and out of a Fanuc over FOCAS: download, upload, folder listing, delete.

Download and upload run on a transfer session of their own (opened with 1); the listing and the
delete are commands on an ordinary session (30i-series file functions: a 256-byte path). Every
result code that is not EW_OK comes back as a `TransferRefused` carrying it.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from gateway.codecs.focas import functions as fn
from gateway.codecs.focas.commands import command
from gateway.codecs.focas.errors import FocasError, describe
from gateway.codecs.focas.frame import SESSION_TRANSFER, Kind, encode_frame
from gateway.codecs.focas.program import CHUNK, download_frames, result_of, start_payload, upload_name
from gateway.codecs.focas.values import DirEntry, decode_dir, path_field
from gateway.errors import SourceError
from gateway.sources.focas.session import FocasSession

FOLDER_PAGE = 20  # entries per folder read
DRAIN_EVERY = 32  # data frames written before waiting for the socket to take them (about 45 KB)


class TransferRefused(SourceError):
    """The controller answered a transfer or a file command with an error code (`code`)."""

    def __init__(self, reason: str, code: int) -> None:
        super().__init__(reason)
        self.code = code


def _check(code: int, what: str) -> None:
    if code:
        raise TransferRefused(f"{what}: the controller refused: {describe(code)}", code)


async def download(
    host: str,
    port: int,
    timeout: float,
    path: str,
    data: bytes,
    progress: Callable[[int], None] | None = None,
) -> None:
    """Store `data` as `path` (folder and name) on the controller."""
    session = FocasSession(host, port, timeout)
    await session.open(SESSION_TRANSFER)
    try:
        start, chunks, end = download_frames(path, data, CHUNK)
        _check(result_of(await session.exchange(start), Kind.DOWNLOAD_START_OK), f"download of {path}")
        sent = 0
        for index, frame in enumerate(chunks, 1):
            session.send(frame)  # no answers to data frames: TCP's window paces them
            sent += len(frame) - 10
            if index % DRAIN_EVERY == 0 or index == len(chunks):
                await session.drain()
                if progress is not None:
                    progress(sent)
        _check(result_of(await session.exchange(end), Kind.DOWNLOAD_END_OK), f"download of {path}")
    except FocasError as exc:
        raise SourceError(f"download of {path}: {exc.reason}") from None
    finally:
        await session.close()


async def upload(host: str, port: int, timeout: float, name: str, limit: int | None = None) -> bytes:
    """The program `name` (a full path, or an O-number) as the controller sends it."""
    session = FocasSession(host, port, timeout)
    await session.open(SESSION_TRANSFER)
    try:
        answer = await session.exchange(encode_frame(Kind.UPLOAD_START, start_payload(upload_name(name))))
        _check(result_of(answer, Kind.UPLOAD_START_OK), f"upload of {name}")
        parts: list[bytes] = []
        size = 0
        while True:
            frame = await session.next_frame()
            if frame.kind == Kind.UPLOAD_END:
                session.send(encode_frame(Kind.UPLOAD_END_OK))
                return b"".join(parts)
            if frame.kind != Kind.UPLOAD_DATA:
                raise SourceError(f"upload of {name}: a frame of type {frame.kind:#06x} in the program")
            size += len(frame.payload)
            if limit is not None and size > limit:
                raise TransferRefused(f"upload of {name}: larger than {limit} bytes", 0)
            parts.append(frame.payload)
    except FocasError as exc:
        raise SourceError(f"upload of {name}: {exc.reason}") from None
    finally:
        await session.close()


async def list_folder(session: FocasSession, folder: str) -> list[DirEntry]:
    field = path_field(folder)
    (count,) = await session.request([command(fn.FOLDER_COUNT, data=field)])
    _check(count.error, f"listing {folder}")
    if len(count.data) < 8:
        raise SourceError(f"listing {folder}: a short answer ({len(count.data)} bytes)")
    dirs, files = struct.unpack_from(">ii", count.data)
    entries: list[DirEntry] = []
    total = max(0, dirs) + max(0, files)
    for first in range(0, total, FOLDER_PAGE):
        (page,) = await session.request([command(fn.READ_FOLDER, first, FOLDER_PAGE, 0, 1, data=field)])
        _check(page.error, f"listing {folder}")
        try:
            entries += decode_dir(page.data)
        except FocasError as exc:
            raise SourceError(f"listing {folder}: {exc.reason}") from None
    return entries


async def delete_file(session: FocasSession, path: str) -> None:
    (reply,) = await session.request([command(fn.DELETE_FILE, data=path_field(path))])
    _check(reply.error, f"deleting {path}")
