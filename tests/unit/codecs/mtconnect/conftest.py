"""The official MTConnect 2.4 schemas, compiled once per session (the Streams one takes seconds)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[4]
# CI has shared/ beside the clone; a worktree under /work/wt/ reaches it at /work/shared.
CANDIDATES = [ROOT.parent / "shared" / "mtconnect", Path("/work/shared/mtconnect")]


def schema_dir() -> Path | None:
    return next((d for d in CANDIDATES if (d / "MTConnectStreams_2.4_1.0.xsd").is_file()), None)


@pytest.fixture(scope="session")
def schemas() -> dict[str, Any]:
    """Document kind ("Devices", "Streams", "Assets", "Error") -> compiled xmlschema XMLSchema10.

    The XSD 1.0 forms of the 2.4 schemas (`_1.0.xsd`): xmlschema's XSD 1.1 validator refuses to
    compile the Streams one (see shared/mtconnect/SOURCES.md).
    """
    xmlschema = pytest.importorskip("xmlschema")
    directory = schema_dir()
    if directory is None:
        pytest.skip(
            f"the MTConnect schemas are not on this machine (looked in {', '.join(map(str, CANDIDATES))})"
        )
    return {
        kind: xmlschema.XMLSchema10(str(directory / f"MTConnect{kind}_2.4_1.0.xsd"))
        for kind in ("Devices", "Streams", "Assets", "Error")
    }


def assert_valid(schemas: dict[str, Any], kind: str, document: str) -> None:
    errors = list(schemas[kind].iter_errors(document))
    assert not errors, f"{len(errors)} schema errors, the first: {errors[0]}"
