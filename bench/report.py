"""Figures, their baselines and targets: one printed table and the same figures as JSON.

Every figure is measured in the same run as its baseline; `ratio` is value / baseline
(for "lower is better" figures too: the targets say which way is good).
"""

from __future__ import annotations

import json
import math
import platform
import sys
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any


@dataclass
class Figure:
    key: str  # stable identifier, e.g. "mirror.opcua.qos0.n1000.r5000.mqtt_rate"
    section: str
    label: str
    value: float | None
    unit: str
    baseline: float | None = None
    baseline_label: str = ""
    note: str = ""

    @property
    def ratio(self) -> float | None:
        if self.value is None or self.baseline is None or not self.baseline:
            return None
        return self.value / self.baseline

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["ratio"] = self.ratio
        return out


@dataclass
class Target:
    """One row of the issue's targets table, judged against a figure of this run."""

    name: str
    must: float
    aim: float | None
    unit: str
    higher_is_better: bool = True
    value: float | None = None
    source: str = ""  # which figure(s) the value comes from, and how
    note: str = ""

    def verdict(self, bound: float | None) -> str | None:
        if bound is None:
            return None
        if self.value is None or (isinstance(self.value, float) and math.isnan(self.value)):
            return "MISS"
        ok = self.value >= bound if self.higher_is_better else self.value <= bound
        return "PASS" if ok else "MISS"

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["must_result"] = self.verdict(self.must)
        out["aim_result"] = self.verdict(self.aim)
        return out


@dataclass
class Results:
    args: dict[str, Any]
    started: datetime = field(default_factory=lambda: datetime.now(UTC))
    figures: list[Figure] = field(default_factory=list)
    targets: list[Target] = field(default_factory=list)  # issue 7's table
    targets_13: list[Target] = field(
        default_factory=list
    )  # issue 13's: against the peer (Node-RED), tighter scale
    targets_15: list[Target] = field(default_factory=list)  # issue 15's: Sparkplug B beside the JSON sink
    targets_17: list[Target] = field(default_factory=list)  # issue 17's: MTConnect
    targets_16: list[Target] = field(default_factory=list)  # issue 16's: the web console
    targets_14: list[Target] = field(default_factory=list)  # issue 14's: serial DNC
    targets_22: list[Target] = field(default_factory=list)  # issue 22's: serial DNC on real device servers
    targets_25: list[Target] = field(default_factory=list)  # issue 25's: FOCAS
    targets_26: list[Target] = field(default_factory=list)  # issue 26's: the Modbus TCP and S7 drivers
    targets_27: list[Target] = field(default_factory=list)  # issue 27's: the umati view at scale
    targets_28: list[Target] = field(default_factory=list)  # issue 28's: QoS 1, the readers, start-up
    targets_29: list[Target] = field(default_factory=list)  # issue 29's: shards
    details: dict[str, Any] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    load: dict[str, Any] = field(default_factory=dict)

    def add(
        self,
        key: str,
        section: str,
        label: str,
        value: float | None,
        unit: str,
        *,
        baseline: float | None = None,
        baseline_label: str = "",
        note: str = "",
    ) -> Figure:
        figure = Figure(key, section, label, _finite(value), unit, _finite(baseline), baseline_label, note)
        self.figures.append(figure)
        return figure

    def get(self, key: str) -> float | None:
        for figure in self.figures:
            if figure.key == key:
                return figure.value
        return None

    def as_dict(self) -> dict[str, Any]:
        return {
            "meta": {
                "started": self.started.isoformat(timespec="seconds"),
                "finished": datetime.now(UTC).isoformat(timespec="seconds"),
                "python": sys.version.split()[0],
                "platform": platform.platform(),
                "cpus": _cpus(),
                "args": self.args,
                "load": self.load,
            },
            "figures": [f.as_dict() for f in self.figures],
            "targets": [t.as_dict() for t in self.targets],
            "targets_13": [t.as_dict() for t in self.targets_13],
            "targets_15": [t.as_dict() for t in self.targets_15],
            "targets_17": [t.as_dict() for t in self.targets_17],
            "targets_16": [t.as_dict() for t in self.targets_16],
            "targets_14": [t.as_dict() for t in self.targets_14],
            "targets_22": [t.as_dict() for t in self.targets_22],
            "targets_25": [t.as_dict() for t in self.targets_25],
            "targets_26": [t.as_dict() for t in self.targets_26],
            "targets_27": [t.as_dict() for t in self.targets_27],
            "targets_28": [t.as_dict() for t in self.targets_28],
            "targets_29": [t.as_dict() for t in self.targets_29],
            "details": self.details,
            "errors": self.errors,
        }

    def write(self, folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        stamp = self.started.strftime("%Y%m%dT%H%M%SZ")
        text = json.dumps(self.as_dict(), indent=2, default=str, allow_nan=False)
        path = folder / f"bench-{stamp}.json"
        path.write_text(text + "\n", encoding="utf-8")
        (folder / "latest.json").write_text(text + "\n", encoding="utf-8")
        return path


def _finite(value: float | None) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _cpus() -> int:
    import os

    return os.cpu_count() or 0


# --- the printed table ---------------------------------------------------------------------------


def fmt(value: float | None, unit: str = "") -> str:
    if value is None:
        return "—"
    if unit == "%":
        return f"{value:.0f} %"
    if unit in ("ms", "s") and abs(value) < 10:
        return f"{value:.2f} {unit}" if unit == "s" else f"{value:.1f} {unit}"
    text = f"{value:,.0f}" if abs(value) >= 100 or float(value).is_integer() else f"{value:.2f}"
    return f"{text} {unit}".rstrip()


def render(results: Results) -> str:
    rows: list[tuple[str, ...]] = []
    section = None
    for f in results.figures:
        if f.section != section:
            section = f.section
            rows.append(("", "", "", "", ""))
            rows.append((f"[{section}]", "", "", "", ""))
        ratio = f"{f.ratio:.2f}" if f.ratio is not None else ""
        baseline = f"{fmt(f.baseline, f.unit)} ({f.baseline_label})" if f.baseline is not None else ""
        rows.append(("  " + f.label, fmt(f.value, f.unit), baseline, ratio, f.note))
    table = _columns(("Figure", "Value", "Baseline (same run)", "Ratio", "Note"), rows)
    out = [table, "", "Targets (issue 7)", _targets(results.targets)]
    if results.targets_13:
        out += ["", "Targets (issue 13)", _targets(results.targets_13)]
    if results.targets_15:
        out += ["", "Targets (issue 15)", _targets(results.targets_15)]
    if results.targets_17:
        out += ["", "Targets (issue 17)", _targets(results.targets_17)]
    if results.targets_25:
        out += ["", "Targets (issue 25)", _targets(results.targets_25)]
    if results.targets_16:
        out += ["", "Targets (issue 16)", _targets(results.targets_16)]
    if results.targets_14:
        out += ["", "Targets (issue 14)", _targets(results.targets_14)]
    if results.targets_22:
        out += ["", "Targets (issue 22)", _targets(results.targets_22)]
    if results.targets_26:
        out += ["", "Targets (issue 26)", _targets(results.targets_26)]
    if results.targets_27:
        out += ["", "Targets (issue 27)", _targets(results.targets_27)]
    if results.targets_28:
        out += ["", "Targets (issue 28)", _targets(results.targets_28)]
    if results.targets_29:
        out += ["", "Targets (issue 29)", _targets(results.targets_29)]
    if results.errors:
        out += ["", "Errors:"] + [f"  - {e}" for e in results.errors]
    return "\n".join(out)


def _targets(targets: list[Target]) -> str:
    trows: list[tuple[str, ...]] = []
    for t in targets:
        unit = t.unit
        trows.append((
            t.name, fmt(t.value, unit), f"{fmt(t.must, unit)}", t.verdict(t.must) or "",
            fmt(t.aim, unit) if t.aim is not None else "—", t.verdict(t.aim) or "—", t.source,
        ))  # fmt: skip
    return _columns(("Target", "Value", "Must", "", "Aim", "", "From"), trows)


def _columns(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    widths = [len(h) for h in header]
    for row in rows:
        for i, cell in enumerate(row):
            widths[i] = max(widths[i], len(cell))
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)).rstrip()]
    lines.append("  ".join("-" * w for w in widths))
    for row in rows:
        lines.append(
            "  ".join(
                c.ljust(w) if i == 0 else c.rjust(w) if i < 4 else c.ljust(w)
                for i, (c, w) in enumerate(zip(row, widths, strict=False))
            ).rstrip()
        )
    return "\n".join(lines)
