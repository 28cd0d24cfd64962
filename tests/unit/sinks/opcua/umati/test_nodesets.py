"""The NodeSets the package ships are the official files of shared/opcua-nodesets, byte for byte.

CI has shared/ beside the clone; a worktree under /work/wt/ reaches it at /work/shared. Without it, the
vendored copies are still checked to be the models the view imports, each with its licence header.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.sinks.opcua.umati.install import NODESET_FILES, nodeset_paths

ROOT = Path(__file__).resolve().parents[5]
CANDIDATES = [ROOT.parent / "shared" / "opcua-nodesets", Path("/work/shared/opcua-nodesets")]
SHARED = next((p for p in CANDIDATES if p.is_dir()), None)


def test_the_package_ships_every_nodeset_with_its_licence() -> None:
    paths = nodeset_paths()
    assert [p.name for p in paths] == list(NODESET_FILES)
    for path in paths:
        head = path.read_text(encoding="utf-8")[:2000]
        assert "OPC Foundation MIT License 1.00" in head, path.name
    assert (paths[0].parent / "SOURCES.md").is_file()


@pytest.mark.skipif(SHARED is None, reason="shared/opcua-nodesets is not beside this checkout")
def test_the_vendored_nodesets_are_the_shared_ones() -> None:
    assert SHARED is not None
    folder = nodeset_paths()[0].parent
    for path in [*nodeset_paths(), folder / "Opc.Ua.MachineTool.Nodeset2.documentation.csv"]:
        assert path.read_bytes() == (SHARED / path.name).read_bytes(), path.name
