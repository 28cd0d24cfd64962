"""`cnc-gateway discover ENDPOINT` picks its driver from the specs' `discovers`, else the default driver."""

from __future__ import annotations

import pytest

from gateway.sources import registry


def _discoverer(endpoint: str) -> str:
    spec = next((s for s in registry.ordered() if s.discovers and endpoint.startswith(s.discovers)), None)
    return registry.DEFAULT if spec is None else spec.type


@pytest.mark.parametrize(
    ("endpoint", "driver"),
    [
        ("focas://10.0.0.7:8193", "focas"),
        ("http://agent:5000", "mtconnect"),
        ("https://agent:5000", "mtconnect"),
        ("opc.tcp://press-3:4840", "opcua"),
    ],
)
def test_each_endpoint_scheme_has_its_driver(endpoint: str, driver: str) -> None:
    assert _discoverer(endpoint) == driver
    spec = registry.find(driver)
    assert spec is not None and spec.discover is not None


def test_no_two_drivers_discover_the_same_scheme() -> None:
    schemes = [scheme for spec in registry.DRIVERS for scheme in spec.discovers]
    assert len(schemes) == len(set(schemes))
