"""A condition may change the model: "does a sticky cart rail lower the cart-pole's success?"
is one config with two conditions on the same states, analysed, judged and verified as any
other. The edited condition must run exactly the model a user gets by editing the XML by hand.
"""

from __future__ import annotations

import hashlib
import json
import re
import subprocess
from pathlib import Path

import mujoco
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT, SNAKEMAKE, copy_workflow, run_snakemake

from mjtrial.config import ConfigError, check_config
from mjtrial.stages.rollout import run_shard
from mjtrial.stages.stamping import config_slice

pytestmark = pytest.mark.end_to_end

FRICTIONLOSS = 2.0  # N, on the cart's rail: enough to change some of the 24 outcomes
STICKY = {"joint": {"cart_slide": {"frictionloss": FRICTIONLOSS}}}


def _config() -> dict:
    config = yaml.safe_load((REPO_ROOT / "config" / "cartpole_latency.yaml").read_text())
    config["experiment"] = "sticky_rail"
    config["states"]["n"] = 24
    config["rollout"]["shard_size"] = 12
    config["analysis"]["n_resamples"] = 300
    config["conditions"] = {
        "sticky": {"latency": 0.0, "model": STICKY},
        "stock": {"latency": 0.0},
    }
    config["design"]["falsifier"].update(treatment="stock", baseline="sticky")
    config.pop("sweep", None)
    config.pop("variants", None)
    return config


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("sticky")
    copy_workflow(workdir)
    (workdir / "config" / "config.yaml").write_text(yaml.safe_dump(_config(), sort_keys=False))
    run_snakemake(workdir)
    return workdir


def _hand_edited_model(workdir: Path, tmp_path: Path) -> Path:
    """The cart-pole's XML (one file, no includes) with the rail's frictionloss written in by
    hand (text, not MjSpec)."""
    source = (workdir / "tasks" / "cartpole_latency" / "cartpole.xml").read_text()
    edited, count = re.subn(
        r'(<joint name="cart_slide")', rf'\1 frictionloss="{FRICTIONLOSS}"', source
    )
    assert count == 1
    # outside the task's folder: every file there is the task's input
    path = tmp_path / "cartpole_sticky_by_hand.xml"
    path.write_text(edited)
    return path


def _mjb_sha256(model: mujoco.MjModel, folder: Path) -> str:
    path = folder / "model.mjb"
    mujoco.mj_saveModel(model, str(path), None)
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_the_edited_condition_runs_the_hand_edited_model(run, tmp_path):
    results = run / "results" / "sticky_rail"
    by_hand = _hand_edited_model(run, tmp_path)
    config = yaml.safe_load((run / "config" / "config.yaml").read_text())
    # the hand-edited file, under the unedited condition, in-process
    config_by_hand = {**config, "conditions": {**config["conditions"]}}
    config_by_hand["conditions"]["sticky"] = {"latency": 0.0}
    table = run_shard(
        condition_slice=config_slice("rollout", config_by_hand, condition="sticky"),
        states_path=results / "states.parquet",
        model_file=by_hand,
        first=0,
        stop=12,
        output_table=tmp_path / "by_hand.parquet",
        nthread=1,
        rule="rollout:by_hand",
        repo_root=run,
    )
    sticky = pq.read_table(results / "rollouts" / "sticky.parquet").slice(0, 12)
    assert table.drop_columns([]).to_pydict() == sticky.to_pydict()
    stock = pq.read_table(results / "rollouts" / "stock.parquet")
    # the edit matters: some outcome or measure differs from the stock rail's
    assert stock.slice(0, 12).to_pydict() != sticky.to_pydict()
    manifest = json.loads((results / "manifest.json").read_text())
    edits = manifest["model"]["condition_edits"]
    assert list(edits) == ["sticky"] and edits["sticky"]["edits"] == STICKY
    hand = _mjb_sha256(mujoco.MjModel.from_xml_path(str(by_hand)), tmp_path)
    assert edits["sticky"]["compiled_sha256"] == hand != manifest["model"]["compiled_sha256"]


def test_the_report_and_summary_say_what_the_condition_changed(run):
    results = run / "results" / "sticky_rail"
    summary = json.loads((results / "analysis" / "summary.json").read_text())
    assert summary["conditions"]["sticky"]["model"] == STICKY
    assert "model" not in summary["conditions"]["stock"]
    report = (results / "report.md").read_text()
    assert "| sticky | latency 0 s, joint cart_slide frictionloss 2 |" in report


def test_a_run_with_an_edited_condition_verifies(run):
    verify = subprocess.run(
        [str(Path(SNAKEMAKE).with_name("mjtrial")), "verify", "results/sticky_rail"],
        cwd=run,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert verify.returncode == 0, verify.stdout + verify.stderr


@pytest.mark.parametrize(
    ("edits", "message"),
    [
        (
            {"joint": {"cart_rail": {"frictionloss": 1.0}}},
            "conditions.sticky.model.joint.cart_rail: the model has no joint of that name",
        ),
        (
            {"joint": {"cart_slide": {"frictionlos": 1.0}}},
            "conditions.sticky.model.joint.cart_slide.frictionlos: unknown or not overridable",
        ),
        (
            {"tendon_x": {"a": {"b": 1}}},
            "conditions.sticky.model.tendon_x: unknown key",
        ),
    ],
)
def test_a_bad_model_edit_is_one_line_naming_its_key(edits, message):
    config = _config()
    config["conditions"]["sticky"]["model"] = edits
    with pytest.raises(ConfigError) as caught:
        check_config(config, source="config/config.yaml", repo_root=REPO_ROOT)
    assert str(caught.value).startswith(f"config/config.yaml: {message}"), str(caught.value)
    assert "\n" not in str(caught.value)
