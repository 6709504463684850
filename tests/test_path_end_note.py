"""The article table's note on trials that ended at the water's boundary (manifest
``sequences[].end``, spec_version 1.2)."""

from evalkit.reports import tables


def seq(cond: str, end: str | None, traj: str = "dock") -> dict:
    s = {"trajectory": traj, "condition": cond}
    return s if end is None else {**s, "end": end}


def test_the_note_counts_boundary_ends_per_condition():
    seqs = [seq("current_0.0", "dock")] * 3 + [seq("current_1.0", "pool_wall")] * 2 + [seq("current_1.0", "dock")]
    note = tables.boundary_end_note(seqs)
    assert "dock/current_1.0 2 of 3 (pool_wall)" in note
    assert "current_0.0" not in note  # every trial reached the dock


def test_no_note_without_boundary_ends_or_before_the_field_existed():
    assert tables.boundary_end_note([seq("clear", "path"), seq("mild", "dock")]) == ""
    assert tables.boundary_end_note([seq("clear", None)]) == ""  # spec_version 1.1: no end
    assert tables.boundary_end_note([]) == ""


def test_several_faces_are_named_and_the_markdown_carries_the_note():
    import pandas as pd

    seqs = [seq("c", "pool_wall"), seq("c", "pool_floor"), seq("c", "path")]
    note = tables.boundary_end_note(seqs)
    assert "dock/c 2 of 3 (pool_floor, pool_wall)" in note
    metrics = pd.DataFrame(
        [{"trajectory": "dock", "condition": "c", "localizer": "led", "n_trials": 3, "P_succ_mean": 0.5}]
    )
    assert note in tables.article_markdown(metrics, with_ci=False, sequences=seqs)
    assert note not in tables.article_markdown(metrics, with_ci=False)


def test_the_schema_plan_and_report_share_the_contracts_list_of_ends():
    import json
    from pathlib import Path

    from blendgen.pipeline import plan
    from datasets_spec import io

    schema = json.loads((Path(io.__file__).parent / "manifest.schema.json").read_text())
    assert tuple(schema["$defs"]["sequence"]["properties"]["end"]["enum"]) == io.SEQUENCE_ENDS
    assert plan.PATH_ENDS == io.SEQUENCE_ENDS and tables.BOUNDARY_ENDS == io.BOUNDARY_ENDS
    assert set(io.BOUNDARY_ENDS) <= set(io.SEQUENCE_ENDS) and "dock" not in io.BOUNDARY_ENDS
