"""bench/scenarios/dnc.py's programs and bench/run.py's `--dnc-gateway`: what "a machine at 8x the estimate"
means in the benchmark is checked against the gateway's own run-time estimate, and a checkout to compare
with must hold a gateway."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.gcode_gen import PACED_FEED, paced_program
from bench.run import build_parser
from bench.scenarios.dnc import fleet_factors
from gateway.codecs.dnc import block_times
from simulator.machine import RAPID

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("factor", [0.5, 1.0, 1.5, 8.0])
def test_a_paced_programs_blocks_are_estimated_at_factor_times_their_real_time(factor: float) -> None:
    rate, pad = 1000.0, 48
    data = paced_program(20_000, factor=factor, rate=rate, pad=pad)
    lines = data.decode().split("\n")
    moves = [i + 1 for i, line in enumerate(lines) if line.startswith("G1 ")]
    assert len(data) >= 20_000 and len(moves) > 300
    assert {len(lines[n - 1]) + 1 for n in moves} == {pad}  # every block `pad` bytes, its line end included
    times = block_times(data.decode())  # the gateway's estimate, its default rapid
    estimated = {round(times[n], 9) for n in moves}
    # The estimate per block, and what the machine at `factor` x makes of it: `rate` bytes per second.
    assert estimated == {round(pad * factor / rate, 9)}
    assert pad / (times[moves[0]] / factor) == pytest.approx(rate)
    at_speed = paced_program(2_000, factor=factor, rate=rate, speed=4.0)  # the tests' rig: no padding
    first = next(line for line in at_speed.decode().split("\n") if line.startswith("G1 "))
    seconds = block_times(at_speed.decode())[at_speed.decode().split("\n").index(first) + 1]
    assert (len(first) + 1) / (seconds / factor / 4.0) == pytest.approx(rate)  # bytes per real second
    assert PACED_FEED * factor <= RAPID  # the simulator's machine is not capped at its rapid


def test_the_fleet_spreads_from_half_to_eight_times_the_estimate() -> None:
    factors = fleet_factors(20)
    assert factors[0] == pytest.approx(0.5) and factors[-1] == pytest.approx(8.0)
    assert factors == sorted(factors) and len(set(factors)) == 20


def test_dnc_gateway_takes_labelled_checkouts_that_hold_a_gateway(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = build_parser().parse_args(["--dnc-gateway", f"before={ROOT}", "--dnc-gateway", "after=."])
    assert args.dnc_gateways == [("before", str(ROOT)), ("after", ".")]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--dnc-gateway", f"old={tmp_path}"])
    assert "no gateway/ package there" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--dnc-gateway", str(ROOT)])
    assert "is not LABEL=PATH" in capsys.readouterr().err
