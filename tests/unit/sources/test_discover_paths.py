from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config.mapping import check_path, tree_conflicts
from gateway.settings.names import SEGMENT_RE
from gateway.sources.browse_paths import assign_paths, sanitize_segment


def keys(*names: str) -> tuple[tuple[str, str], ...]:
    """A browse path whose node identities are the names themselves."""
    return tuple(("/".join(names[: i + 1]), name) for i, name in enumerate(names))


def test_sanitize_keeps_plain_names_and_cleans_odd_ones() -> None:
    assert sanitize_segment("ActPos") == "ActPos"
    assert sanitize_segment("Spindle-1.Speed") == "Spindle-1.Speed"
    assert sanitize_segment("::AsGlobalPV") == "AsGlobalPV"
    assert sanitize_segment("gAxis[0]") == "gAxis_0"
    assert sanitize_segment("[3]") == "3"
    assert sanitize_segment("Temp °C") == "Temp_C"
    assert sanitize_segment("Höhe") == "Hohe"
    assert sanitize_segment(".hidden") == "_.hidden"
    assert sanitize_segment("温度") == "Node"
    assert sanitize_segment("") == "Node"


def test_common_leading_folders_are_dropped() -> None:
    paths = assign_paths(
        [keys("PLC", "Modules", "::AsGlobalPV", "gSpeed"), keys("PLC", "Modules", "::Laser", "headTemp")]
    )
    assert paths == ["AsGlobalPV/gSpeed", "Laser/headTemp"]


def test_structure_members_become_children() -> None:
    paths = assign_paths(
        [keys("Machine", "gAxis", "ActPos"), keys("Machine", "gAxis", "Referenced"), keys("Machine", "Feed")]
    )
    assert paths == ["gAxis/ActPos", "gAxis/Referenced", "Feed"]


def test_array_elements_are_named_by_their_index() -> None:
    paths = assign_paths([keys("M", "gAxis", "gAxis[0]", "ActPos"), keys("M", "gAxis", "gAxis[1]", "ActPos")])
    assert paths == ["gAxis/0/ActPos", "gAxis/1/ActPos"]


def test_a_variable_with_mapped_children_moves_into_its_folder() -> None:
    paths = assign_paths([keys("M", "Spindle"), keys("M", "Spindle", "Override"), keys("M", "Other")])
    assert paths == ["Spindle/Value", "Spindle/Override", "Other"]
    paths = assign_paths([keys("M", "Spindle"), keys("M", "Spindle", "value"), keys("M", "Other")])
    assert paths == ["Spindle/Value_2", "Spindle/value", "Other"]


def test_names_that_clash_after_cleaning_or_by_case_get_numbered() -> None:
    paths = assign_paths([keys("M", "a b"), keys("M", "a_b"), keys("M", "A_B"), keys("M", "x")])
    assert paths == ["a_b", "a_b_2", "A_B_3", "x"]


def test_same_browse_name_on_two_nodes_gives_two_paths() -> None:
    paths = assign_paths(
        [(("ns=2;s=M", "M"), ("ns=2;s=1", "Pos")), (("ns=2;s=M", "M"), ("ns=3;s=1", "Pos")), keys("N")]
    )
    assert paths == ["M/Pos", "M/Pos_2", "N"]


def test_reserved_top_level_names_get_a_prefix() -> None:
    paths = assign_paths([keys("M", "Status", "Temp"), keys("M", "jobs"), keys("M", "Axis", "Status")])
    assert paths == ["Controller_Status/Temp", "Controller_jobs", "Axis/Status"]


names = st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=12)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(names, min_size=1, max_size=4), min_size=1, max_size=25))
def test_any_browse_names_give_valid_unique_non_conflicting_paths(browse: list[list[str]]) -> None:
    # identities are the name chains, so browse paths share folders and may end where another
    # continues (a variable with members); a browse visits every node once, hence the dict
    key_paths = list(dict.fromkeys(keys(*names) for names in browse))
    paths = assign_paths(key_paths)
    assert len(paths) == len(key_paths)
    for path in paths:
        check_path(path)
        assert all(SEGMENT_RE.match(seg) for seg in path.split("/"))
    assert len({p.lower() for p in paths}) == len(paths)
    assert tree_conflicts(paths) == []
