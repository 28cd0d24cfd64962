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


class _Lxml:
    """lxml's validator behind xmlschema's `iter_errors`, for the schemas lxml can compile offline."""

    def __init__(self, path: Path) -> None:
        from lxml import etree

        self._etree = etree
        self._schema = etree.XMLSchema(etree.parse(str(path)))

    def iter_errors(self, document: str) -> list[str]:
        root = self._etree.fromstring(document.encode("utf-8"))
        if self._schema.validate(root):
            return []
        return str(self._schema.error_log).splitlines()


@pytest.fixture(scope="session")
def schemas() -> dict[str, Any]:
    """Document kind ("Devices", "Streams", "Assets", "Error") -> a validator with `iter_errors(text)`.

    The XSD 1.0 forms of the 2.4 schemas (`_1.0.xsd`; xmlschema's XSD 1.1 validator refuses to
    compile the Streams one, see shared/mtconnect/SOURCES.md). Streams and Error go through lxml
    (ten times faster on a 10,000-item /current); Devices and Assets through xmlschema, because
    lxml would fetch their xlink import from the network.
    """
    xmlschema = pytest.importorskip("xmlschema")
    pytest.importorskip("lxml")
    directory = schema_dir()
    if directory is None:
        pytest.skip(
            f"the MTConnect schemas are not on this machine (looked in {', '.join(map(str, CANDIDATES))})"
        )
    return {
        "Streams": _Lxml(directory / "MTConnectStreams_2.4_1.0.xsd"),
        "Error": _Lxml(directory / "MTConnectError_2.4_1.0.xsd"),
        "Devices": xmlschema.XMLSchema10(str(directory / "MTConnectDevices_2.4_1.0.xsd")),
        "Assets": xmlschema.XMLSchema10(str(directory / "MTConnectAssets_2.4_1.0.xsd")),
    }


def assert_valid(schemas: dict[str, Any], kind: str, document: str) -> None:
    errors = list(schemas[kind].iter_errors(document))
    assert not errors, f"{len(errors)} schema errors, the first: {errors[0]}"
