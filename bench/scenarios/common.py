"""Pieces the scenarios share: configuration files, node id lists, final-value checks, profiles."""

from __future__ import annotations

import asyncio
import collections
import contextlib
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from bench.breakdown import breakdown, parse_collapsed
from bench.procs import ROOT, free_port

GATEWAY_URI = "urn:cnc-gateway"


def ids_file(path: Path, uri: str, identifiers: Sequence[str]) -> Path:
    """One `nsu=<uri>;s=<id>` per line, for bench.agents.opcua_sub."""
    path.write_text("".join(f"nsu={uri};s={ident}\n" for ident in identifiers), encoding="utf-8")
    return path


def gateway_ids(machine: str, paths: Sequence[str]) -> list[str]:
    """The gateway's node ids spell the machine and the path (gateway/sinks/opcua/address_space.py)."""
    return [f"{machine}/{path}" for path in paths]


def noise_paths(first: int, count: int, per_folder: int = 200) -> list[str]:
    return [f"Noise/g{i // per_folder:03d}/v{i:05d}" for i in range(first, first + count)]


def noise_topic(machine: str, path: str, prefix: str = "cnc") -> str:
    return f"{prefix}/{machine}/{path.lower()}"


def write_gateway(
    folder: Path,
    mappings: dict[str, str],
    *,
    mqtt_port: int | None,
    mqtt: dict[str, Any] | None = None,
    inbox: dict[str, Any] | None = None,
    opcua_port: int | None = None,
    extra: dict[str, Any] | None = None,
) -> tuple[Path, str]:
    """A gateway file and its mapping files in `folder`; returns (gateway file, OPC UA endpoint)."""
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for name, text in mappings.items():
        (folder / f"{name}.yaml").write_text(text, encoding="utf-8")
        names.append(f"{name}.yaml")
    endpoint = f"opc.tcp://127.0.0.1:{opcua_port or free_port()}/cnc-gateway"
    doc: dict[str, Any] = {
        "opcua": {"endpoint": endpoint},
        "state_dir": "state",
        "log_level": "warning",
        "inbox": {"host": "127.0.0.1", "port": free_port(), **(inbox or {})},
        "machines": names,
    }
    if mqtt_port is not None:
        doc["mqtt"] = {"port": mqtt_port, "client_id": f"bench-gw-{folder.name}", **(mqtt or {})}
    doc.update(extra or {})  # other sections of the gateway file (sparkplug:)
    path = folder / "gateway.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return path, endpoint


def expected_last(written: int, count: int, first: int = 0, total: int | None = None) -> list[float]:
    """The last value noise wrote to variables first..first+count-1 after `written` changes
    round robin over `total` variables (0.0: never written)."""
    total = total or count
    out = []
    for i in range(first, first + count):
        if written < i + 1:
            out.append(0.0)
        else:
            out.append(float(written - ((written - 1 - i) % total)))
    return out


def matches(seen: Sequence[float | None], expected: Sequence[float]) -> int:
    return sum(1 for a, b in zip(seen, expected, strict=False) if a is not None and a == b)


# --- profiles -------------------------------------------------------------------------------------


def py_spy() -> str | None:
    found = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    return found if Path(found).exists() else None


async def profile(pid: int, seconds: float, out: Path) -> dict[str, Any] | None:
    """Sample `pid` with py-spy for `seconds` (with native frames where py-spy can unwind them): the top
    functions by own and by total time, and the share of each part of the gateway (bench/breakdown.py)."""
    exe = py_spy()
    if exe is None:
        return None
    raw = out.with_suffix(".txt")
    err = b""
    for native in (["--native"], []):  # --native needs unwinding support; without it, Python frames only
        proc = await asyncio.create_subprocess_exec(
            exe, "record", "--pid", str(pid), "--duration", str(max(1, round(seconds))), "--rate", "100",
            "--format", "raw", "--output", str(raw), *native,
            stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        _, err = await proc.communicate()
        if proc.returncode == 0 and raw.exists():
            text = raw.read_text(errors="replace")
            summary = summarize_collapsed(text)
            stacks = parse_collapsed(text)
            summary["native"] = bool(native)
            summary["parts"] = breakdown(stacks)
            summary["parts_samples"] = sum(n for _, n in stacks)
            summary["file"] = str(raw)
            return summary
    return {"error": err.decode(errors="replace")[-500:]}


def summarize_collapsed(text: str, top: int = 15, thread: str = "BaseEventLoop._run_once") -> dict[str, Any]:
    """Own time and total time per function from py-spy's collapsed stacks (`a;b;c 12`), counting only
    the stacks that pass through `thread` (the event loop: idle worker threads are not where time goes)."""
    own: collections.Counter[str] = collections.Counter()
    total: collections.Counter[str] = collections.Counter()
    samples = 0
    for line in text.splitlines():
        stack, _, count_text = line.rpartition(" ")
        if thread not in stack:
            continue
        with contextlib.suppress(ValueError):
            count = int(count_text)
            frames = [_short(f) for f in stack.split(";") if f]
            if not frames:
                continue
            samples += count
            own[frames[-1]] += count
            for frame in set(frames):
                total[frame] += count
    if not samples:
        return {"samples": 0}
    return {
        "samples": samples,
        "own": [(name, round(100.0 * n / samples, 1)) for name, n in own.most_common(top)],
        "total": [(name, round(100.0 * n / samples, 1)) for name, n in total.most_common(top * 2)],
    }


def _short(frame: str) -> str:
    """`_push (gateway/sinks/opcua/server.py:340)` -> `_push (gateway/sinks/opcua/server.py)`."""
    name, _, where = frame.partition(" (")
    where = where.rstrip(")")
    path = where.rsplit(":", 1)[0]
    for marker in ("site-packages/", f"{ROOT}/", "python3.11/"):
        if marker in path:
            path = path.split(marker, 1)[1]
    return f"{name} ({path})" if path else name
