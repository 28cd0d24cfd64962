"""docs/architecture.md's adapters table is the registries' (issue 24: docs that cannot drift)."""

from __future__ import annotations

from tests.architecture_doc import DOC, END, expected, rows


def test_the_adapters_table_is_the_one_the_registries_give() -> None:
    text = DOC.read_text()
    assert text == expected(text), (
        "docs/architecture.md's adapters table is stale: python -m tests.architecture_doc --write"
    )


def test_every_adapter_has_a_folder_and_a_summary_in_the_table() -> None:
    table = DOC.read_text().split(END, 1)[0]
    for kind, name, folder, summary in rows():
        assert summary and f"| {kind} | {name} | `{folder}` | {summary} |" in table
