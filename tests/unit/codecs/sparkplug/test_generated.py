"""The committed sparkplug_b_pb2.py/.pyi are what the pinned generator makes of sparkplug_b.proto."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from gateway.codecs.sparkplug import protoc

PINNED = re.compile(r'"grpcio-tools==([^"]+)"')


def pinned_version() -> str:
    pyproject = Path(protoc.HERE).parents[2] / "pyproject.toml"
    match = PINNED.search(pyproject.read_text(encoding="utf-8"))
    assert match, "pyproject.toml pins no grpcio-tools"
    return match.group(1)


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    installed = protoc.generator_version()
    if installed is None:
        pytest.skip("grpcio-tools (the protobuf code generator) is not installed: pip install -e '.[proto]'")
    assert installed == pinned_version(), (
        f"grpcio-tools {installed} is installed, pyproject.toml pins {pinned_version()}: run `make install`"
    )
    out = tmp_path_factory.mktemp("pb2")
    protoc.generate(out)
    return out


@pytest.mark.parametrize("name", protoc.GENERATED)
def test_the_committed_module_is_the_generators_output(regenerated: Path, name: str) -> None:
    committed = (protoc.HERE / name).read_text(encoding="utf-8")
    fresh = (regenerated / name).read_text(encoding="utf-8")
    assert committed == fresh, f"{name} does not match sparkplug_b.proto: run `make sparkplug-proto`"


def test_the_runtime_range_is_the_one_the_module_names() -> None:
    header = (protoc.HERE / "sparkplug_b_pb2.py").read_text(encoding="utf-8")
    version = re.search(r"# Protobuf Python Version: (\d+)\.(\d+)\.(\d+)", header)
    assert version
    major, minor, patch = version.groups()
    pyproject = (Path(protoc.HERE).parents[2] / "pyproject.toml").read_text(encoding="utf-8")
    assert f'"protobuf>={major}.{minor}.{patch},<{int(major) + 1}"' in pyproject
