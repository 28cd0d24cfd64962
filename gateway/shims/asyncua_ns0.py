"""asyncua's standard namespace, built once and then read from a cache file node by node, when asked for.

Every asyncua server builds the 6,174 nodes of the OPC UA standard namespace (ns=0)
at start-up: about half a second on the bench machine, and some 24 MB that stay,
although a client reads a few dozen of them (the Server object, the type tree it
browses). The nodes are constant data for a given asyncua and Python: the same as
a module's bytecode, they can be cached. The first server to start builds them as
before and writes each node's record, pickled, to one file; the next ones load only
the file's index and read a node's record the first time something asks for it
(`LazyNodes`, asyncua's `AddressSpace._nodes`). What a client reads is the record
the build made (tests/integration/opcua/test_address_space_identity.py compares a
server built the old way with one loaded from the cache, node by node).

asyncua has the same idea (`Server.init(shelf_file)`), but through `shelve`, which
here falls back to `dbm.dumb` (no gdbm): three files, a file opened per read, and
a mapping that forgets the nodes it has not loaded when iterated.

The file is a cache: keyed by asyncua's and Python's versions and this format,
written once (a temporary file linked into place, never replaced), and only used
when the current user owns it and its folder, which nobody else may write (it is
unpickled). Anything wrong with it, and the server builds the namespace as before.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
import stat
import sys
import tempfile
import time
import weakref
import zlib
from collections.abc import Callable, Iterator, MutableMapping
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

FORMAT = 1  # bump when what is pickled changes shape (shims/asyncua_server.py's record classes)
_MAGIC = b"cnc-gateway ns0 cache\n"
ENV = "CNC_GATEWAY_CACHE"  # the cache folder; "off": no cache
_UNREADABLE = (OSError, EOFError, ValueError, TypeError, AttributeError, ImportError, pickle.UnpicklingError)
_UNWRITABLE = (OSError, TypeError, AttributeError, RecursionError, pickle.PicklingError)


def default_cache_dir() -> Path | None:
    """$CNC_GATEWAY_CACHE, else $XDG_CACHE_HOME/cnc-gateway, else ~/.cache/cnc-gateway; None if "off"."""
    chosen = os.environ.get(ENV)
    if chosen:
        return None if chosen.lower() == "off" else Path(chosen)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "cnc-gateway"


def cache_file(folder: Path) -> Path:
    """The cache file for this asyncua, this Python and this format, in `folder`. The name includes the
    fields of the records pickled (asyncua's NodeData, the slim records): change them, a new file."""
    from asyncua import __version__ as asyncua_version
    from asyncua.server.address_space import NodeData

    from gateway.shims.asyncua_server import SlimAttributeValue

    shape = repr((FORMAT, SlimAttributeValue.__slots__, NodeData.__init__.__code__.co_names))
    digest = zlib.crc32(shape.encode()) & 0xFFFF
    py = "{}{}".format(*sys.version_info[:2])
    return folder / f"asyncua-{asyncua_version}-ns0-py{py}-f{FORMAT}-{digest:04x}.bin"


class LazyNodes(MutableMapping[Any, Any]):
    """asyncua's node dict, whose standard nodes come from the cache file the first time they are asked for.

    Everything asyncua does with its `_nodes` works as with a dict: get, set, delete,
    `in`, and iteration, which yields the nodes not loaded yet too (without loading
    them). Nodes added later (ours) live in `cache` only. `add_file` adds the nodes of another file of
    the same shape (the NodeSets' cache, asyncua_nodesets.py).
    """

    __slots__ = ("__weakref__", "_fd", "_index", "cache")

    def __init__(self, fd: int, index: dict[Any, tuple[int, int]]) -> None:
        self.cache: dict[Any, Any] = {}
        self._fd = fd
        self._index: dict[Any, tuple[int, ...]] = dict(index)  # (offset, size[, fd of another file])
        weakref.finalize(self, os.close, fd)

    def __getitem__(self, key: Any) -> Any:
        try:
            return self.cache[key]
        except KeyError:
            return self._load(key)

    def get(self, key: Any, default: Any = None) -> Any:
        node = self.cache.get(key)
        if node is not None:
            return node
        if key in self._index:
            return self._load(key)
        return default

    def add_file(self, fd: int, index: dict[Any, tuple[int, int]]) -> None:
        """Nodes read from another file (open at `fd`, closed with this mapping), as from the first."""
        weakref.finalize(self, os.close, fd)
        for key, (offset, size) in index.items():
            if key not in self.cache:
                self._index[key] = (offset, size, fd)

    def _load(self, key: Any) -> Any:
        entry = self._index[key]  # KeyError: not a node
        fd = entry[2] if len(entry) > 2 else self._fd
        node = pickle.loads(os.pread(fd, entry[1], entry[0]))
        del self._index[key]
        self.cache[key] = node
        return node

    def __setitem__(self, key: Any, value: Any) -> None:
        self._index.pop(key, None)
        self.cache[key] = value

    def __delitem__(self, key: Any) -> None:
        if self.cache.pop(key, None) is None:
            del self._index[key]

    def __contains__(self, key: object) -> bool:
        return key in self.cache or key in self._index

    def __iter__(self) -> Iterator[Any]:
        yield from list(self.cache)
        yield from [key for key in list(self._index) if key not in self.cache]

    def __len__(self) -> int:
        return len(self.cache) + len(self._index)

    def loaded(self) -> list[Any]:
        """The node ids whose records are in memory."""
        return list(self.cache)


def loaded_node_ids(nodes: Any) -> list[Any] | None:
    """The ids of the nodes in memory if `nodes` is a LazyNodes, else None (all of them are)."""
    return nodes.loaded() if isinstance(nodes, LazyNodes) else None


def _trusted(path: Path) -> bool:
    """Whether `path` and its folder belong to this user and nobody else may write them."""
    uid = os.getuid() if hasattr(os, "getuid") else None
    for item in (path.parent, path):
        info = item.stat()
        if uid is not None and info.st_uid != uid:
            return False
        if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
            return False
    return True


def load(path: Path) -> LazyNodes | None:
    """The nodes of the cache file at `path`, or None if there is none fit to use (said at DEBUG)."""
    try:
        if not path.is_file() or not _trusted(path):
            return None
        fd = os.open(path, os.O_RDONLY)
    except OSError as exc:
        log.debug("OPC UA standard namespace cache %s not used: %s", path, exc)
        return None
    try:
        head = os.pread(fd, len(_MAGIC) + 16, 0)
        if not head.startswith(_MAGIC):
            raise ValueError("not a cache file")
        index_at, index_size = (
            int.from_bytes(head[len(_MAGIC) + i : len(_MAGIC) + i + 8], "little") for i in (0, 8)
        )
        index = pickle.loads(os.pread(fd, index_size, index_at))
        if not isinstance(index, dict):
            raise ValueError("no index")
        return LazyNodes(fd, index)
    except _UNREADABLE as exc:  # a damaged or foreign file: build the namespace instead
        os.close(fd)
        log.warning("OPC UA standard namespace cache %s not used: %s", path, exc)
        return None


def save(path: Path, nodes: dict[Any, Any]) -> None:
    """Write `nodes` (node id → asyncua NodeData) as a cache file at `path`, unless one is there already.

    Written to a temporary file and linked into place: a reader never sees half a
    file, and a file in use is never replaced. Failures are logged, never raised."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        if path.exists():
            return
        _forget_abandoned(path.parent)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".ns0-", suffix=".tmp")
    except OSError as exc:
        log.debug("OPC UA standard namespace cache %s not written: %s", path, exc)
        return
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(_MAGIC + bytes(16))
            index: dict[Any, tuple[int, int]] = {}
            at = len(_MAGIC) + 16
            for nodeid, node in nodes.items():
                blob = pickle.dumps(node, pickle.HIGHEST_PROTOCOL)
                out.write(blob)
                index[nodeid] = (at, len(blob))
                at += len(blob)
            table = pickle.dumps(index, pickle.HIGHEST_PROTOCOL)
            out.write(table)
            out.seek(len(_MAGIC))
            out.write(at.to_bytes(8, "little") + len(table).to_bytes(8, "little"))
        with contextlib.suppress(FileExistsError):  # another server wrote it meanwhile: theirs stays
            os.link(tmp, path)
    except _UNWRITABLE as exc:  # a node that cannot be pickled, a full disk: no cache, nothing else changes
        log.warning("OPC UA standard namespace cache %s not written: %s", path, exc)
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def _forget_abandoned(folder: Path, age: float = 600.0) -> None:
    """Remove temporary files a server killed while writing left behind (older than `age` seconds)."""
    now = time.time()
    for stale in folder.glob(".ns0-*.tmp"):
        with contextlib.suppress(OSError):
            if now - stale.stat().st_mtime > age:
                stale.unlink()


def use_cache(iserver: Any, folder: Path) -> Callable[[], bool]:
    """Make this asyncua InternalServer load its standard namespace from the cache in `folder` (writing it
    when there is none yet, then reading it as the next servers will). Call before `Server.init`; the
    returned function says whether the cache was there already (after init)."""
    path = cache_file(folder)
    build = iserver.load_standard_address_space  # the class's, with its wrappers (asyncua_server.py)
    used = [False]

    async def load_standard_address_space(shelf_file: Any = None) -> None:
        aspace = iserver.aspace
        nodes = load(path)
        if nodes is not None:
            aspace._nodes = nodes
            used[0] = True
            return
        await build(shelf_file)
        save(path, aspace._nodes)
        # From the file from now on, as the next servers will: what was built is freed (17 MB).
        nodes = load(path)
        if nodes is not None:
            aspace._nodes = nodes

    iserver.load_standard_address_space = load_standard_address_space
    return lambda: used[0]
