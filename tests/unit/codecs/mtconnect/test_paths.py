"""`path=` filters: the XPath subset clients use, over the probe document's shape."""

from __future__ import annotations

import pytest

from gateway.codecs.mtconnect.errors import ErrorCode, InvalidPath
from gateway.codecs.mtconnect.paths import PathIndex, parse_path

from .machines import shop

CATALOG = shop(2)
INDEX = PathIndex(CATALOG)
M1 = CATALOG.devices[0]


def ids(path: str, device: bool = False) -> set[str]:
    return set(INDEX.select(parse_path(path), M1 if device else None))


def items_of(prefix: str, *names: str) -> set[str]:
    return {f"{prefix}_{n}" for n in names}


AXIS_X = items_of("m1", "Xpos", "Xcmd", "Xfeed", "Xload", "Xtravel")
BOTH_X = AXIS_X | {i.replace("m1_", "m2_") for i in AXIS_X}


@pytest.mark.parametrize(
    ("path", "expected"),
    [
        ('//Linear[@name="X"]', BOTH_X),
        ("//Linear[@name='X']", BOTH_X),
        ('//Linear[@id="m1_x"]/DataItems/DataItem', AXIS_X),
        ('//Linear[@name="X"]/DataItems', BOTH_X),
        ('//DataItem[@type="POSITION" and @subType="ACTUAL" and @name="Xact"]', {"m1_Xpos", "m2_Xpos"}),
        (
            '//DataItem[@type="EXECUTION" or @type="CONTROLLER_MODE"]',
            items_of("m1", "exec", "mode") | items_of("m2", "exec", "mode"),
        ),
        (
            '//Controller//DataItem[@category="EVENT"]',
            {
                f"m{i}_{n}"
                for i in (1, 2)
                for n in ("exec", "mode", "program", "block", "line", "parts", "feed_ovr")
            },
        ),
        (
            '//Axes/Components/Linear[@name="X"]/DataItems/DataItem[@category="CONDITION"]',
            {"m1_Xtravel", "m2_Xtravel"},
        ),
        ('//*[@id="m2_exec"]', {"m2_exec"}),
        ('//DataItem[@id="m1_exec"]|//DataItem[@id="m2_mode"]', {"m1_exec", "m2_mode"}),
        (
            '/MTConnectDevices/Devices/Device[@name="laser2"]/DataItems/DataItem[@type="AVAILABILITY"]',
            {"m2_avail"},
        ),
        (
            '//Device[@uuid="urn:example:laser:1"]/DataItems',
            items_of("m1", "avail", "estop", "asset_chg", "asset_rem"),
        ),
        (
            '//DataItem[@subType != "ACTUAL"][@type="POSITION"]',
            {"m1_Xcmd", "m1_Ycmd", "m1_Zcmd", "m2_Xcmd", "m2_Ycmd", "m2_Zcmd"},
        ),
        ("//m:DataItem[@coordinateSystem]", {"m1_pathpos", "m2_pathpos"}),
    ],
)
def test_supported_paths_select_their_data_items(path: str, expected: set[str]) -> None:
    assert ids(path) == expected


def test_a_component_selects_every_data_item_below_it() -> None:
    axes = ids("//Axes")
    assert len(axes) == 2 * 3 * 5 and axes >= AXIS_X
    assert ids("//Devices") == set(CATALOG.items)


def test_a_device_scopes_the_path() -> None:
    assert ids("//Axes", device=True) == {i for i in ids("//Axes") if i.startswith("m1_")}
    assert ids('/DataItems/DataItem[@type="AVAILABILITY"]', device=True) == {"m1_avail"}


@pytest.mark.parametrize(
    ("path", "reason"),
    [
        ("Axes", "starts with / or //"),
        ("//Linear[1]", "only attribute tests"),
        ("//Linear[last()]", "only attribute tests"),
        ("//DataItem[contains(@type, 'POS')]", "only attribute tests"),
        ("//Axes/..", "an element name or *"),
        ("//Axes/.", "an element name or *"),
        ("//child::Axes", "axes and functions"),
        ("//text()", "axes and functions"),
        ('//Linear[@name="X"', "a predicate is"),
        ('//Linear[@name="X]', "not closed"),
        ("//Linear[@name=X]", "a quoted value"),
        ("(//Axes)", "starts with / or //"),
        ("//Axes |", "starts with / or //"),
        ("//Axes extra", "unexpected"),
        ("", "empty"),
        ("/" * 3000, "longer than"),
        ("|".join(["//Axes"] * 40), "alternatives"),
    ],
)
def test_unsupported_paths_are_refused_with_a_reason(path: str, reason: str) -> None:
    with pytest.raises(InvalidPath, match=reason) as caught:
        parse_path(path)
    assert caught.value.code is ErrorCode.INVALID_PATH


@pytest.mark.parametrize("path", ["//Spindle", '//DataItem[@type="NO_SUCH"]', "//Axes/DataItems"])
def test_a_path_that_selects_nothing_is_refused(path: str) -> None:
    with pytest.raises(InvalidPath, match="selects no data item"):
        INDEX.select(parse_path(path))
