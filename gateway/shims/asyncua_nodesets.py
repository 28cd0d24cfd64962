"""NodeSet2 files (companion specifications) imported into asyncua once, then loaded from a cache file.

asyncua's `import_xml` of the umati view's six NodeSets takes about 1.6 s (most of it checking for
missing reverse references, node by node), about as long as the rest of a 10,000-variable start-up. The
nodes it makes are constant data for given files, asyncua, Python and namespaces already registered,
as the standard namespace is (asyncua_ns0.py): the first server imports the files while recording what the
import added (the new nodes whole, and the references it appended to nodes that were there) and pickles
that, each node's record apiece; the next ones register the same namespaces (at the same indices,
checked) and read a recorded node the first time something asks for it, as the standard namespace's
are (most are types no client browses), appending the recorded references. The file is trusted as
the standard namespace's is (this user's, in a folder nobody else may write, since it is unpickled);
anything wrong with it, and the files are imported as before.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import pickle
import sys
import tempfile
from collections.abc import Awaitable, Callable, Iterator, MutableMapping, Sequence
from importlib.metadata import version
from pathlib import Path
from typing import Any

from asyncua import ua

from gateway.shims.asyncua_ns0 import LazyNodes, _trusted
from gateway.shims.ua import new_node_id

log = logging.getLogger(__name__)

FORMAT = 2
_MAGIC = b"cnc-gateway nodesets cache\n"
_NAMESPACE_ARRAY = new_node_id(ua.ObjectIds.Server_NamespaceArray)
_UNREADABLE = (OSError, EOFError, ValueError, TypeError, AttributeError, ImportError, pickle.UnpicklingError)
_UNWRITABLE = (OSError, TypeError, AttributeError, RecursionError, pickle.PicklingError)


class _Recording(MutableMapping[Any, Any]):
    """asyncua's node table, noting which nodes the import adds and how many references each node it
    touches had before (asyncua only appends references)."""

    def __init__(self, nodes: MutableMapping[Any, Any]) -> None:
        self.nodes = nodes
        self.added: set[Any] = set()
        self.before: dict[Any, int] = {}

    def _note(self, key: Any, record: Any) -> Any:
        if record is not None and key not in self.before and key not in self.added:
            self.before[key] = len(record.references)
        return record

    def __getitem__(self, key: Any) -> Any:
        return self._note(key, self.nodes[key])

    def get(self, key: Any, default: Any = None) -> Any:
        record = self.nodes.get(key)
        return default if record is None else self._note(key, record)

    def __setitem__(self, key: Any, value: Any) -> None:
        if key not in self.nodes:
            self.added.add(key)
        self.nodes[key] = value

    def __delitem__(self, key: Any) -> None:
        del self.nodes[key]

    def __contains__(self, key: object) -> bool:
        return key in self.nodes

    def __iter__(self) -> Iterator[Any]:
        return iter(self.nodes)

    def __len__(self) -> int:
        return len(self.nodes)


def cache_key(files: Sequence[Path], namespaces: Sequence[str]) -> str:
    digest = hashlib.sha256()
    for part in (str(FORMAT), version("asyncua"), sys.version, *namespaces):
        digest.update(part.encode() + b"\0")
    for path in files:
        digest.update(path.read_bytes())
    return digest.hexdigest()[:24]


async def import_nodesets(
    server: Any,
    files: Sequence[Path],
    folder: Path | None,
    import_one: Callable[[Path], Awaitable[Any]],
) -> bool:
    """Import `files` into the asyncua `server` (through `import_one`), from the cache in `folder` when it
    has them (None: no cache). Returns whether the cache was used."""
    aspace = server.iserver.aspace
    namespaces: list[str] = list(await server.get_namespace_array())
    if folder is None:
        for path in files:
            await import_one(path)
        return False
    path = folder / f"nodesets-{cache_key(files, namespaces)}.pickle"
    cached = _load(path)
    if cached is not None and await _apply(server, aspace, cached):
        return True
    recording = _Recording(aspace._nodes)
    aspace._nodes = recording
    try:
        for item in files:
            await import_one(item)
    finally:
        aspace._nodes = recording.nodes
    nodes = recording.nodes
    after: list[str] = list(await server.get_namespace_array())
    appended = {
        key: list(nodes[key].references[count:])
        for key, count in recording.before.items()
        if key not in recording.added and key != _NAMESPACE_ARRAY and len(nodes[key].references) > count
    }
    added = {key: nodes[key] for key in recording.added}
    _save(path, added, after[len(namespaces) :], appended)
    return False


async def _apply(server: Any, aspace: Any, cached: _Cached) -> bool:
    base = len(await server.get_namespace_array())
    for offset, uri in enumerate(cached.namespaces):
        if await server.register_namespace(uri) != base + offset:
            log.warning("NodeSets cache not used: namespace %s is not where it was", uri)
            cached.close()
            return False
    nodes = aspace._nodes
    if isinstance(nodes, LazyNodes):  # read a node the first time something asks for it, as the standard's
        nodes.add_file(cached.fd, cached.index)
    else:
        for key, (offset, size) in cached.index.items():
            nodes[key] = pickle.loads(os.pread(cached.fd, size, offset))
        cached.close()
    for key, references in cached.appended.items():
        record = nodes.get(key)
        if record is not None:
            record.references.extend(references)
    return True


class _Cached:
    """An open cache file: the index of its node records, and what else the import did."""

    def __init__(self, fd: int, table: dict[str, Any]) -> None:
        self.fd = fd
        self.index: dict[Any, tuple[int, int]] = table["index"]
        self.namespaces: list[str] = table["namespaces"]
        self.appended: dict[Any, list[Any]] = table["appended"]

    def close(self) -> None:
        os.close(self.fd)


def _load(path: Path) -> _Cached | None:
    try:
        if not path.is_file() or not _trusted(path):
            return None
        fd = os.open(path, os.O_RDONLY)
    except OSError as exc:
        log.debug("NodeSets cache %s not used: %s", path, exc)
        return None
    try:
        head = os.pread(fd, len(_MAGIC) + 16, 0)
        if not head.startswith(_MAGIC):
            raise ValueError("not a NodeSets cache file")
        at = int.from_bytes(head[len(_MAGIC) : len(_MAGIC) + 8], "little")
        size = int.from_bytes(head[len(_MAGIC) + 8 :], "little")
        table = pickle.loads(os.pread(fd, size, at))
        if not isinstance(table, dict) or not {"index", "namespaces", "appended"} <= set(table):
            raise ValueError("not a NodeSets cache file")
        return _Cached(fd, table)
    except _UNREADABLE as exc:
        os.close(fd)
        log.warning("NodeSets cache %s not used: %s", path, exc)
        return None


def _save(path: Path, added: dict[Any, Any], namespaces: list[str], appended: dict[Any, list[Any]]) -> None:
    """Each node's record pickled apiece (read lazily, as the standard namespace's cache), then a table:
    where each is, the namespaces, the references appended. Written to a temporary file and linked into
    place; failures are logged, never raised."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        if path.exists():
            return
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".nodesets-", suffix=".tmp")
    except OSError as exc:
        log.debug("NodeSets cache %s not written: %s", path, exc)
        return
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(_MAGIC + bytes(16))
            index: dict[Any, tuple[int, int]] = {}
            at = len(_MAGIC) + 16
            for key, record in added.items():
                blob = pickle.dumps(record, pickle.HIGHEST_PROTOCOL)
                out.write(blob)
                index[key] = (at, len(blob))
                at += len(blob)
            table = {"index": index, "namespaces": namespaces, "appended": appended}
            blob = pickle.dumps(table, pickle.HIGHEST_PROTOCOL)
            out.write(blob)
            out.seek(len(_MAGIC))
            out.write(at.to_bytes(8, "little") + len(blob).to_bytes(8, "little"))
        with contextlib.suppress(FileExistsError):
            os.link(tmp, path)
    except _UNWRITABLE as exc:
        log.warning("NodeSets cache %s not written: %s", path, exc)
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
