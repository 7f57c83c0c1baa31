"""`pytest --time-breakdown`'s table (tests/time_breakdown.py), from lines written by hand."""

from __future__ import annotations

from time_breakdown import COPY, OWN, PROCESS, SNAKEMAKE, VERIFY, summary


def test_the_table_sums_each_category_and_each_file():
    lines = [
        {"test": "tests/a.py::one", "spent": {SNAKEMAKE: 10.0, OWN: 2.0}, "calls": {SNAKEMAKE: 2}},
        {"test": "tests/a.py::two", "spent": {VERIFY: 4.0, OWN: 1.0}, "calls": {VERIFY: 1}},
        {"test": "tests/b.py::one", "spent": {PROCESS: 30.0, COPY: 1.0, OWN: 0.5}, "calls": {}},
    ]
    table = summary(lines, files=1)
    assert table[0] == "time breakdown: 3 tests, 48 s summed over the workers"
    assert table[1].split() == ["10", "s", "21%", "Snakemake", "runs", "2", "calls"]
    assert table[2].split() == ["4", "s", "8%", "verify", "1", "call"]
    assert table[3].split() == ["30", "s", "62%", "other", "processes"]
    assert table[5].split()[:3] == ["4", "s", "7%"] and table[5].endswith(OWN)
    # one file shown, the longer: b.py's 31.5 s against a.py's 17 s
    assert table[7].split() == ["32", "0", "0", "30", "1", "0", "tests/b.py"]
    assert len(table) == 8


def test_a_snakemake_process_counts_as_a_snakemake_run():
    from time_breakdown import _process_category

    assert _process_category(["/venv/bin/snakemake", "-c2"]) == SNAKEMAKE
    assert _process_category(["/venv/bin/python", "-m", "snakemake"]) == PROCESS
    assert _process_category("git status", shell=True) == PROCESS
