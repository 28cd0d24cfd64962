"""The noise mode's pure parts: its variables, its mapping file for the gateway, its CLI flags."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from gateway.config.loader import load_mapping
from simulator.cli import build_parser
from simulator.noise import NoiseSpec, noise_mapping, noise_variables, split_machines
from simulator.variables import Variable


def test_noise_variables_are_pushed_doubles_in_folders_of_at_most_per_folder() -> None:
    spec = NoiseSpec(450, 1000.0, per_folder=200)
    variables = noise_variables(spec)
    assert len({v.node_id for v in variables}) == 450
    assert all(
        isinstance(v, Variable) and v.pushed and v.type == "Double" and not v.writable for v in variables
    )
    parents = {v.ancestors[-1][0] for v in variables}
    assert parents == {"::Noise:g000", "::Noise:g001", "::Noise:g002"}  # 200 + 200 + 50, never flat
    assert variables[0].node_id == "::Noise:g000.v00000" and variables[449].node_id == "::Noise:g002.v00449"


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"variables": 0}, "at least one variable"),
    ({"variables": 5, "per_folder": 0}, "per_folder"),
    ({"variables": 5, "rate": -1.0}, "rate"),
    ({"variables": 5, "rate": math.nan}, "rate"),
])  # fmt: skip
def test_a_nonsensical_spec_is_refused_with_the_reason(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        NoiseSpec(**kwargs)  # type: ignore[arg-type]


def test_the_generated_mapping_loads_and_names_every_noise_variable(tmp_path: Path) -> None:
    spec = NoiseSpec(1000)
    path = tmp_path / "noise.yaml"
    path.write_text(
        noise_mapping(spec, "opc.tcp://127.0.0.1:4841", machine="bench-noise", first=200, count=300)
    )
    mapping = load_mapping(path, environ={})
    assert mapping.machine == "bench-noise" and len(mapping.variables) == 300
    first, last = mapping.variables[0], mapping.variables[-1]
    assert (first.path, first.source) == (
        "Noise/g001/v00200",
        "nsu=urn:cnc-simulator:plc;s=::Noise:g001.v00200",
    )
    assert last.path == "Noise/g002/v00499" and str(last.type) == "Double"
    assert mapping.driver.publishing_interval == 10 and mapping.defaults.queue_size == 10


def test_a_mapping_beyond_the_noise_variables_is_refused() -> None:
    with pytest.raises(ValueError, match="not all among"):
        noise_mapping(NoiseSpec(100), "opc.tcp://127.0.0.1:4841", first=50, count=51)


def test_machines_split_the_variables_evenly_or_not_at_all() -> None:
    assert split_machines(NoiseSpec(10_000), 20)[19] == (9500, 500)
    with pytest.raises(ValueError, match="equal machines"):
        split_machines(NoiseSpec(1001), 20)


def test_cli_flags() -> None:
    args = build_parser().parse_args(
        ["--noise-variables", "500", "--noise-rate", "max", "--noise-per-folder", "50"]
    )
    assert (args.noise_variables, args.noise_rate, args.noise_per_folder) == (500, math.inf, 50)
    assert build_parser().parse_args(["--noise-variables", "5", "--noise-rate", "250"]).noise_rate == 250.0
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--noise-rate", "fast"])
