"""Regenerate sparkplug_b_pb2.py and .pyi from sparkplug_b.proto with protobuf's own generator.

The generator is protoc as shipped in grpcio-tools, pinned in pyproject.toml (extra `proto`,
which `make install` brings in through the test extra); nothing here runs at gateway run time.
`make sparkplug-proto` writes the modules beside the .proto; the unit test
tests/unit/codecs/sparkplug/test_generated.py writes them into a temporary folder and compares.

    python -m gateway.codecs.sparkplug.protoc [OUT_DIR]
"""

from __future__ import annotations

import sys
from importlib import metadata
from pathlib import Path

HERE = Path(__file__).resolve().parent
PROTO = HERE / "sparkplug_b.proto"
GENERATED = ("sparkplug_b_pb2.py", "sparkplug_b_pb2.pyi")
GENERATOR = "grpcio-tools"


def generator_version() -> str | None:
    """The installed grpcio-tools version, or None when it is not installed."""
    try:
        return metadata.version(GENERATOR)
    except metadata.PackageNotFoundError:
        return None


def generate(out_dir: Path) -> list[Path]:
    """Run protoc on sparkplug_b.proto, writing the generated modules into `out_dir`."""
    from grpc_tools import protoc  # the generator is a development tool, not a runtime dependency

    out_dir.mkdir(parents=True, exist_ok=True)
    args = [
        "protoc",
        f"--proto_path={HERE}",
        f"--python_out={out_dir}",
        f"--pyi_out={out_dir}",
        str(PROTO),
    ]
    status = protoc.main(args)
    if status != 0:
        raise RuntimeError(f"protoc failed with status {status} on {PROTO}")
    return [out_dir / name for name in GENERATED]


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    out_dir = Path(args[0]) if args else HERE
    if generator_version() is None:
        print(f"{GENERATOR} is not installed: pip install -e '.[proto]'", file=sys.stderr)
        return 2
    for path in generate(out_dir):
        print(f"wrote {path} ({GENERATOR} {generator_version()})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
