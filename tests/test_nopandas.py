"""A rollout job's process never imports pandas (pyarrow would, at its first conversion: about
0.3 s of the job's CPU), and its table and recordings are the same as with pandas imported."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT

from mjtrial.recording.read import read_episode
from mjtrial.stages.stamping import config_slice
from mjtrial.stages.states import build_states

pytestmark = pytest.mark.end_to_end

# what workflow/scripts/rollout.py does (with `pyarrow_without_pandas` or without), on 6 states
JOB = """
import json, sys
from pathlib import Path
args = json.loads(sys.argv[1])
if args.pop("without_pandas"):
    from mjtrial.nopandas import pyarrow_without_pandas
    pyarrow_without_pandas()
from mjtrial.stages.rollout import run_shard
for key in ("states_path", "model_file", "output_table", "output_recording"):
    args[key] = Path(args[key])
run_shard(**args)
print(json.dumps({"pandas": "pandas" in sys.modules}))
"""


def run_job(tmp: Path, states: Path, *, without_pandas: bool) -> tuple[Path, Path, bool]:
    config = yaml.safe_load((REPO_ROOT / "config/config.yaml").read_text())
    out = tmp / ("without" if without_pandas else "with")
    out.mkdir()
    args = {
        "without_pandas": without_pandas,
        "condition_slice": dict(config_slice("rollout", config, condition="fast")),
        "states_path": str(states),
        "model_file": str(REPO_ROOT / config["model"]),
        "first": 0,
        "stop": 6,
        "output_table": str(out / "shard.parquet"),
        "output_recording": str(out / "recordings"),
        "nthread": 1,
        "rule": "rollout:fast#0",
    }
    done = subprocess.run(
        [sys.executable, "-c", JOB, json.dumps(args)],
        capture_output=True,
        text=True,
        check=True,
        env=os.environ | {"PYTHONPATH": str(REPO_ROOT / "src")},
        cwd=REPO_ROOT,
    )
    pandas = json.loads(done.stdout.strip().splitlines()[-1])["pandas"]
    return out / "shard.parquet", out / "recordings", pandas


def test_rollout_job_without_pandas_writes_the_same(tmp_path):
    config = yaml.safe_load((REPO_ROOT / "config/config.yaml").read_text())
    states = tmp_path / "states.parquet"
    build_states(
        states_slice={**config_slice("states", config), "n": 6}, output=states, repo_root=REPO_ROOT
    )
    table, recordings, pandas = run_job(tmp_path, states, without_pandas=True)
    ref_table, ref_recordings, ref_pandas = run_job(tmp_path, states, without_pandas=False)
    assert not pandas
    assert ref_pandas  # what the job imported before, through pyarrow alone
    ours, theirs = pq.read_table(table), pq.read_table(ref_table)
    assert ours.replace_schema_metadata(None).equals(theirs.replace_schema_metadata(None))
    assert ours.schema.metadata.keys() == theirs.schema.metadata.keys()
    for state_id in range(6):
        a = read_episode(recordings, condition="fast", state_id=state_id)
        b = read_episode(ref_recordings, condition="fast", state_id=state_id)
        assert a.keys() == b.keys()
        for key in a:
            assert np.array_equal(a[key], b[key]), (state_id, key)
