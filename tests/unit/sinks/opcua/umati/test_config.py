"""The `umati:` section's check of the variables it names (gateway/sinks/opcua/umati/config.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.config.loader import load_mapping
from gateway.errors import ConfigError

MAPPING = """\
machine: m1
driver: {{endpoint: "opc.tcp://127.0.0.1:4841"}}
variables:
  - {{path: Machine/State, source: "ns=2;s=s", type: Int16}}
umati:
  identification: {{Manufacturer: ACME, SerialNumber: "42", ProductInstanceUri: "urn:acme:42"}}
  program:
    name: demo
    state: {{variable: Machine/State, values: {{0: Ended, 1: Running}}}}
    job_identifier: {{variable: {job_variable}}}
"""


def write(tmp_path: Path, job_variable: str) -> Path:
    path = tmp_path / "m1.yaml"
    path.write_text(MAPPING.format(job_variable=job_variable))
    return path


def test_a_job_variable_without_a_job_queue_leaves_its_node_empty_instead_of_refusing_the_file(
    tmp_path: Path,
) -> None:
    """The laser's default map binds JobIdentifier to Jobs/LastDelivered; a copy of that mapping without
    `jobs:` is still a valid mapping (the node stays empty)."""
    mapping = load_mapping(write(tmp_path, "Jobs/LastDelivered"), environ={})
    assert mapping.jobs is None


def test_a_variable_the_mapping_does_not_have_is_still_refused_with_its_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as caught:
        load_mapping(write(tmp_path, "Machine/Nope"), environ={})
    assert "umati.program.job_identifier.variable: 'Machine/Nope' is not a variable of this mapping" in str(
        caught.value
    )
