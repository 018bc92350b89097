"""The stress report: the guide (per-area totals), the listing of every case, and a record naming no directory."""

from __future__ import annotations

import json
import re

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


def _rows(count: int) -> list[dict]:
    """``count`` cases in a listed area ("nothing lost", every third failing) and one in an unlisted area."""
    rows = [
        {"area": "nothing lost", "case": f"kill {i}", "expected": "resumes", "observed": "ok", "passed": i % 3 != 0}
        for i in range(count)
    ]
    return rows + [{"area": "odd area", "case": "one | two", "expected": "e", "observed": "o", "passed": True}]


def _report(rows: list[dict]) -> str:
    return stress_report.format_report(rows, None, 1, 10.0, 5.0)


def test_guide_gives_each_area_its_totals_and_leaves_the_cases_to_the_listing():
    """The guide's line count depends on the areas, not the cases; each area's row counts its
    cases, passes and failures, and the contract note of an area that has one is there."""
    rows = _rows(30)
    guide = _report(rows)

    assert len(guide.splitlines()) == len(_report(_rows(3000)).splitlines())
    assert "**31 cases, 21 pass, 10 fail**" in guide
    nothing_lost = next(line for line in guide.splitlines() if line.startswith("| [Nothing lost]"))
    assert nothing_lost.endswith("| 30 | 20 | **10** |")
    assert next(line for line in guide.splitlines() if line.startswith("| [Odd area]")).endswith("| 1 | 1 | 0 |")
    assert stress_report.AREA_NOTES["nothing lost"] in guide
    assert not any(f"kill {i} |" in guide for i in range(30))


def test_listing_holds_every_case_once_and_links_back_to_the_guide(tmp_path):
    """Every case is one row of the listing, a failure marked FAIL and a '|' escaped; the
    links between the two files resolve from where run_stress writes them."""
    rows = _rows(30)
    report = tmp_path / "docs" / "stress.md"
    cases = stress_report.format_cases(rows, report.name, 1, 10.0)
    lines = cases.splitlines()

    for row in rows:
        matching = [line for line in lines if line.startswith(f"| {row['case'].replace('|', chr(92) + '|')} |")]
        assert len(matching) == 1
        assert matching[0].endswith("| pass |" if row["passed"] else "| **FAIL** |")
    listing = stress_report.cases_path(report)
    link_back = re.search(r"\]\(([^)#]+)\)", cases).group(1)
    assert (listing.parent / link_back).resolve() == report.resolve()
    link_out = re.search(r"\]\(([^)#]+\.md)\)", _report(rows)).group(1)
    assert (report.parent / link_out).resolve() == listing.resolve()
