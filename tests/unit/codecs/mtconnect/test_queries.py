"""REST request targets into checked requests (the refusals are in tests/corpus/mtconnect/requests.yaml)."""

from __future__ import annotations

from gateway.codecs.mtconnect.paths import PathIndex
from gateway.codecs.mtconnect.queries import Request, parse_request, select_items

from .machines import shop

CATALOG = shop(2)
INDEX = PathIndex(CATALOG)


def test_routes_and_defaults() -> None:
    assert parse_request("/") == Request("probe")
    assert parse_request("/laser1") == Request("probe", device="laser1")
    assert parse_request("/laser1/probe?format=JSON&pretty=true") == Request(
        "probe", device="laser1", format="json", pretty=True
    )
    assert parse_request("/current?at=5") == Request("current", at=5)
    sample = parse_request("/laser2/sample?from=7&count=-3&interval=250&heartbeat=1000&path=%2F%2FAxes")
    assert sample == Request(
        "sample", device="laser2", from_=7, count=-3, interval=250, heartbeat=1000, path="//Axes"
    )
    assert parse_request("/assets?type=CuttingTool&removed=true&count=5") == Request(
        "assets", asset_type="CuttingTool", removed=True, count=5
    )
    assert parse_request("/asset/T1;T2").asset_ids == ("T1", "T2")


def test_select_items_narrows_by_device_then_path() -> None:
    assert select_items(parse_request("/current"), CATALOG, INDEX) is None
    laser2 = select_items(parse_request("/laser2/current"), CATALOG, INDEX)
    assert laser2 is not None and laser2 == CATALOG.device_items(CATALOG.devices[1])
    axes = select_items(parse_request("/laser2/current?path=//Linear[@name='X']"), CATALOG, INDEX)
    assert axes is not None and axes < laser2 and {i[:3] for i in axes} == {"m2_"}
