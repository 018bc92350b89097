"""The stress record written beside docs/stress.md names files, not the directories they were in."""

from __future__ import annotations

import json

from conftest import absolute_paths

from benchmarks import stress_report


def test_record_names_no_directory_of_the_machine(tmp_path):
    """A failing case's message names its file under pytest's temporary folder; the JSON record
    keeps the message and the file name but not the folder."""
    bad = tmp_path / "work" / "huge.bvh"
    row = {
        "case": "bad motion",
        "expected": "exit 2",
        "observed": f"exit 2: {bad}: line 20: value 1e+40",
        "passed": True,
    }
    fuzz = {"cases": [{"input": str(bad), "seconds": 1.5}]}
    assert absolute_paths([row, fuzz]) != []  # the check below can fail

    record = stress_report.without_paths({"rows": [row], "fuzz": fuzz})

    assert absolute_paths(record) == []
    assert record["rows"][0]["observed"].endswith("work/huge.bvh: line 20: value 1e+40")
    assert record["rows"][0]["passed"] is True and record["fuzz"]["cases"][0]["seconds"] == 1.5
    assert json.loads(json.dumps(record)) == record
