"""The benchmark harness itself, on a tiny load: it measures what arrives and writes figures that add up.

One mirror configuration (in-process source, 50 variables, 500 changes/s for one
second) through a real gateway process, Mosquitto and both subscriber processes;
no timing is asserted, only that the harness counts what it should.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

pytest.importorskip("psutil")  # the bench extra (make bench installs it)

from bench.context import Context, Settings
from bench.report import Results, render
from bench.scenarios import mirror
from bench.targets import judge


async def test_a_tiny_mirror_run_counts_every_change_and_reports_it(tmp_path: Path) -> None:
    settings = Settings.quick_run()
    settings.warmup, settings.window = 0.3, 1.0
    settings.mirror_sizes, settings.mirror_rates, settings.mirror_qos = [50], [500.0], [1]
    settings.mirror_sources = ["inproc"]
    ctx = Context(settings, tmp_path, Results(args={}))
    ctx.log = lambda text: None  # type: ignore[method-assign]

    await mirror.run(ctx)

    assert not ctx.results.errors
    data = ctx.results.details["mirror"]["inproc.qos1.n50"]
    (step,) = data["steps"]
    assert step["offered"] > 0 and step["received"] > 0 and step["mqtt"] > 0
    assert all(math.isfinite(step[k]) for k in ("offered", "received", "mqtt", "opcua", "cpu"))
    assert (
        step["latency"]["n"] > 0
        and step["latency"]["p50"] <= step["latency"]["p99"] <= step["latency"]["max"]
    )
    final = data["final"]
    assert final["written"] > 0
    assert (
        final["mqtt_match"] == final["opcua_match"] == 50
    )  # both subscribers end at the source's last values

    judge(ctx)
    table = render(ctx.results)
    assert "N=50 QoS 1 @500/s: MQTT delivered" in table and "Targets (issue 7)" in table
    path = ctx.results.write(tmp_path / "results")
    written = json.loads(path.read_text())
    assert written == json.loads((tmp_path / "results" / "latest.json").read_text())
    assert {"meta", "figures", "targets", "details", "errors"} <= set(written)
    keys = {f["key"] for f in written["figures"]}
    assert {"mirror.inproc.qos1.n50.r500.mqtt_rate", "mirror.inproc.qos1.n50.final_mqtt"} <= keys
    assert len(written["targets"]) == 8
