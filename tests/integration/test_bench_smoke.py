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
from bench.scenarios import mirror, peer
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


async def test_the_peers_gateway_step_says_where_the_age_of_its_values_accrued(tmp_path: Path) -> None:
    """The gateway's side of the peer scenario (Node-RED is not needed for it): each step carries the ages
    at the gateway's ingest and MQTT write and the subscriber's unread backlog, beside the subscriber's own
    latency, so a run tells age before the gateway from age inside it and after it."""
    settings = Settings.quick_run()
    settings.warmup, settings.window = 0.3, 1.0
    settings.peer_rates = [500.0, math.inf]
    ctx = Context(settings, tmp_path, Results(args={}))
    ctx.log = lambda text: None  # type: ignore[method-assign]

    out = await peer.run_party(ctx, "gateway")

    step, flat = out["steps"]
    # Flat out, a C subscriber measures the same window's latency too (the target is judged there).
    assert not step["latency_c"] and flat["rate"] is None
    c = flat["latency_c"]
    assert c["n"] > 0 and c["p50"] <= c["p99"] <= c["max"]
    assert step["delivered"] > 0
    ages = step["ages"]
    for point in ("ingest", "write"):
        assert ages[point]["n"] > 0 and ages[point]["p50"] <= ages[point]["p99"] <= ages[point]["max"]
    assert ages["write"]["n"] >= step["latency"]["n"] / 8 * 0.9  # a sample of what was delivered (STRIDE)
    assert ages["subscriber_backlog"]["n"] > 0  # the subscriber's socket was sampled in the window
    assert "at the gateway's ingest" in peer.where(step)
    assert out["final"]["match"] == peer.N  # every topic ends at the source's last value
