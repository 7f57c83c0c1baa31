"""The `end_to_end` mark (tests/conftest.py): a test in an unmarked file cannot run Snakemake,
so `pytest -m "not end_to_end"` stays the quick selection."""

from __future__ import annotations

import pytest
from conftest import run_snakemake


def test_an_unmarked_test_that_runs_snakemake_fails_before_the_run(tmp_path):
    missing = tmp_path / "no workflow here"
    with pytest.raises(AssertionError, match=r"mark its file `pytestmark = pytest.mark.end_to_"):
        run_snakemake(missing, "-n")
    assert not missing.exists()


@pytest.mark.end_to_end
def test_a_marked_test_runs_it(tmp_path):
    proc = run_snakemake(tmp_path, "-n", check=False)  # no Snakefile: Snakemake itself says so
    assert proc.returncode != 0 and "No Snakefile found" in proc.stdout + proc.stderr
