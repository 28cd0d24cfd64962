"""The standard namespace's cache (gateway/shims/asyncua_ns0.py), on real asyncua servers.

That a client sees the same nodes from a server loaded from the cache as from asyncua's own build is
tests/integration/opcua/test_address_space_identity.py; here: the file, the mapping, and refusals.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import pytest
from asyncua import Server, ua

from gateway.shims.asyncua_ns0 import LazyNodes, cache_file, load, loaded_node_ids, use_cache
from gateway.shims.asyncua_server import NO_CALLBACKS, slim_attribute_values

pytestmark = pytest.mark.asyncio

SERVER_STATE = ua.NodeId(ua.ObjectIds.Server_ServerStatus_State)
BASE_OBJECT_TYPE = ua.NodeId(ua.ObjectIds.BaseObjectType)


async def _server(folder: Path) -> tuple[Server, bool]:
    slim_attribute_values()
    server = Server()
    used = use_cache(server.iserver, folder)
    await server.init()
    return server, used()


async def test_the_first_server_builds_and_writes_it_the_next_reads_it_node_by_node(tmp_path: Path) -> None:
    folder = tmp_path / "cache"
    first, used = await _server(folder)
    assert not used and cache_file(folder).is_file()
    assert isinstance(first.iserver.aspace._nodes, LazyNodes)  # then read from it, as the next ones will
    assert oct(folder.stat().st_mode & 0o777) == oct(0o700)
    second, used = await _server(folder)
    assert used
    nodes = second.iserver.aspace._nodes
    assert isinstance(nodes, LazyNodes)
    loaded = loaded_node_ids(nodes)
    assert loaded is not None and len(loaded) < 200  # what init touched, not the 6,000 others
    assert set(first.iserver.aspace.keys()) == set(second.iserver.aspace.keys())  # without loading them
    assert len(loaded_node_ids(nodes) or ()) == len(loaded)
    node = nodes[BASE_OBJECT_TYPE]
    assert BASE_OBJECT_TYPE in nodes.loaded()
    assert [r.NodeId for r in node.references] == [
        r.NodeId for r in first.iserver.aspace._nodes[BASE_OBJECT_TYPE].references
    ]
    # A record read from the file shares the one empty callbacks mapping, as a built one does.
    held = nodes[SERVER_STATE].attributes[ua.AttributeIds.Value]
    assert held.datachange_callbacks is NO_CALLBACKS or held.datachange_callbacks == {}


async def test_the_mapping_behaves_as_a_dict(tmp_path: Path) -> None:
    await _server(tmp_path)
    server, used = await _server(tmp_path)
    assert used
    nodes = server.iserver.aspace._nodes
    total = len(nodes)
    assert nodes.get(ua.NodeId(999999, 7)) is None and ua.NodeId(999999, 7) not in nodes
    with pytest.raises(KeyError):
        nodes[ua.NodeId(999999, 7)]
    resting = next(nodeid for nodeid in nodes if nodeid not in nodes.loaded())
    assert resting in nodes
    del nodes[resting]  # never loaded: gone all the same
    assert resting not in nodes and len(nodes) == total - 1
    assert nodes.get(resting) is None
    with pytest.raises(KeyError):
        del nodes[resting]
    mine = ua.NodeId(1, 2)
    nodes[mine] = "x"
    assert nodes[mine] == "x" and len(nodes) == total and list(nodes).count(mine) == 1


async def test_a_damaged_or_foreign_file_is_not_used_and_the_namespace_is_built(tmp_path: Path) -> None:
    path = cache_file(tmp_path)
    path.write_bytes(b"cnc-gateway ns0 cache\n" + bytes(16) + b"garbage")
    server, used = await _server(tmp_path)
    assert not used and len(server.iserver.aspace.keys()) > 5000
    path.write_bytes(pickle.dumps({"not": "a cache"}))
    assert load(path) is None


@pytest.mark.skipif(not hasattr(os, "getuid"), reason="POSIX permissions")
async def test_a_file_others_may_write_is_not_unpickled(tmp_path: Path) -> None:
    await _server(tmp_path)
    path = cache_file(tmp_path)
    assert load(path) is not None
    path.chmod(0o666)
    assert load(path) is None
    path.chmod(0o600)
    tmp_path.chmod(0o777)
    try:
        assert load(path) is None
    finally:
        tmp_path.chmod(0o700)


async def test_a_temporary_file_left_by_a_killed_writer_goes_when_the_cache_is_next_written(
    tmp_path: Path,
) -> None:
    abandoned, recent = tmp_path / ".ns0-abandoned.tmp", tmp_path / ".ns0-writing.tmp"
    for path in (abandoned, recent):
        path.write_bytes(b"half a cache")
    os.utime(abandoned, (0, 0))
    _, used = await _server(tmp_path)
    assert not used and cache_file(tmp_path).is_file()
    assert not abandoned.exists() and recent.exists()  # another server may be writing that one
