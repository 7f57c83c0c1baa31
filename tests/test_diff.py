"""`mjtrial diff`: two small runs that differ in one config value, in the model's physics, or
not at all (one rebuilt from the other's archive on another checkout)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import copy_workflow, edit_config, run_snakemake
from scipy.stats import binomtest

from mjtrial import provenance, recording
from mjtrial.cli import main
from mjtrial.diff.found import compare_effects, rollout_groups
from mjtrial.diff.gate import failures
from mjtrial.diff.source import Run
from mjtrial.recording.divergence import first_divergence

pytestmark = pytest.mark.end_to_end

RESULTS = Path("results") / "research_mode"
MODEL = Path("models") / "gantry_gripper" / "gantry_gripper.xml"


def _small(config):
    config["states"]["n"] = 32
    config["rollout"]["shard_size"] = 32
    config["analysis"]["n_resamples"] = 500


def _build(folder: Path, edit=None, model_edit=None) -> Path:
    copy_workflow(folder)
    edit_config(folder, _small)
    if edit:
        edit_config(folder, edit)
    if model_edit:
        (folder / MODEL).write_text(model_edit((folder / MODEL).read_text()))
    run_snakemake(folder)
    return folder


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """`a` as configured; `lift` with the fast lift nearly as slow as the slow one (one config
    value); `friction` with the pads' sliding friction 0.8 -> 0.5 in the model."""
    make = tmp_path_factory.mktemp
    return {
        "a": _build(make("a")),
        "lift": _build(make("lift"), edit=lambda c: c["conditions"]["fast"].update(lift_time=1.2)),
        "friction": _build(
            make("friction"),
            model_edit=lambda t: t.replace('friction="0.8 0.003', 'friction="0.5 0.003'),
        ),
    }


def _diff(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["diff", *map(str, args)])
    out = capsys.readouterr()
    return code, out.out, out.err


def _success(run: Path, condition: str) -> dict[int, bool]:
    table = pq.read_table(run / RESULTS / "rollouts" / f"{condition}.parquet").to_pylist()
    return {row["state_id"]: row["success"] for row in table}


def test_one_config_value_names_the_key_the_condition_and_the_flips(runs, tmp_path, capsys):
    a, b = runs["a"] / RESULTS, runs["lift"] / RESULTS
    code, out, _ = _diff(capsys, a, b, "--json", "--out", tmp_path / "d")
    assert code == 0
    diff = json.loads(out)
    made = diff["made"]
    assert [r["key"] for r in made["config"]] == ["conditions.fast.lift_time"]
    assert (made["config"][0]["a"], made["config"][0]["b"]) == (0.15, 1.2)
    assert not made["code"] and not made["model"] and not made["versions"]
    assert not made["platform"] and not made["commit"]
    # Every rollout stamp records the machine's CPU and the job's simulation threads.
    stamp = provenance.read_stamp(a / "rollouts" / "fast" / "shard-00000.parquet")
    assert stamp["extra"]["threads"] == 1
    assert stamp["platform"]["cpu_model"] and "sse2" in stamp["platform"]["cpu_flags_fp"]
    # The flips, as the two tables say: only the fast condition moved.
    before, after = _success(runs["a"], "fast"), _success(runs["lift"], "fast")
    flipped = sorted(s for s in before if before[s] != after[s])
    assert flipped
    fast = diff["conditions"]["fast"]
    assert [f["state_id"] for f in fast["flipped"]] == flipped
    assert diff["conditions"]["slow"]["flipped"] == []
    only_b = sum(after[s] and not before[s] for s in flipped)
    expected_p = binomtest(min(only_b, len(flipped) - only_b), len(flipped), 0.5).pvalue
    assert fast["paired"]["p_value"] == pytest.approx(min(1.0, expected_p), rel=1e-9)
    # Each flip's divergence: the recordings agree exactly before it, and part at it.
    for flip in fast["flipped"]:
        d = flip["divergence"]
        series = [
            recording.read_episode(
                r / "rollouts" / "fast", condition="fast", state_id=flip["state_id"]
            )
            for r in (a, b)
        ]
        i = int(np.flatnonzero(np.isclose(series[0]["time"], d["time"], rtol=0, atol=1e-9))[0])
        assert d["step"] == [int(series[0]["step"][i])] * 2
        keys = set(series[0]) - {"time", "step"}
        assert all(np.array_equal(series[0][k][:i], series[1][k][:i]) for k in keys)
        assert np.abs(series[0][d["quantity"]][i] - series[1][d["quantity"]][i]).max() > 1e-6
    # Both runs' recordings of every flip, side by side.
    held = recording.list_recordings(tmp_path / "d" / "replay" / "diff.rrd")
    ids = {r["recording_id"] for r in held}
    assert ids >= {f"{side}-fast-fast-state-{s:06d}" for s in flipped for side in "ab"}


def test_the_verdict_gate_fails_when_the_falsifier_s_verdict_changes(runs, tmp_path, capsys):
    verdicts = [
        json.loads((r / RESULTS / "analysis" / "summary.json").read_text())["falsifier"]["verdict"]
        for r in (runs["a"], runs["lift"])
    ]
    assert verdicts[0] != verdicts[1]
    code, _, err = _diff(
        capsys,
        runs["a"] / RESULTS,
        runs["lift"] / RESULTS,
        "--fail-on",
        "verdict",
        "--out",
        tmp_path,
    )
    assert code == 1
    assert f"verdict changed: {verdicts[0]} -> {verdicts[1]}" in err


def test_a_physics_change_is_caught_with_mcnemar_s_p(runs, tmp_path, capsys):
    a, b = runs["a"] / RESULTS, runs["friction"] / RESULTS
    before, after = _success(runs["a"], "fast"), _success(runs["friction"], "fast")
    only_a = sum(before[s] and not after[s] for s in before)
    only_b = sum(after[s] and not before[s] for s in before)
    p = binomtest(min(only_a, only_b), only_a + only_b, 0.5).pvalue
    assert p < 0.05  # the planted change moves the fast lift beyond noise
    code, out, err = _diff(capsys, a, b, "--fail-on", "changed", "--out", tmp_path)
    assert code == 1
    assert "fast: success" in err and f"McNemar exact p = {p:.3g} < 0.05" in err
    assert "model: files.gantry_gripper.xml:" in out
    # At a level the change does not pass, the gate passes.
    code, _, _ = _diff(capsys, a, b, "--fail-on", "changed", "--level", "1e-9", "--out", tmp_path)
    assert code == 0


def test_a_run_rebuilt_from_its_zip_on_another_checkout_is_identical(
    runs, tmp_path, capsys, monkeypatch
):
    a = runs["a"]
    archive = tmp_path / "a.zip"
    monkeypatch.chdir(a)
    assert main(["crate", str(RESULTS), "--zip", str(archive)]) == 0
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    other = tmp_path / "other"
    with zipfile.ZipFile(archive) as z:
        z.extractall(other)
    # Rebuilt there from scratch by its own package: every output gets a new stamp.
    run_snakemake(other, "--forceall", env={"PYTHONPATH": str(other / "src")})
    for b in (other / RESULTS, archive):
        code, out, err = _diff(capsys, a / RESULTS, b, "--fail-on", "any", "--out", tmp_path)
        assert code == 0, err
        assert "0 differ" in out and "Flipped episodes: 0" in out
        assert "nothing differs" in out
    code, out, _ = _diff(capsys, a / RESULTS, other / RESULTS, "--json", "--out", tmp_path)
    outputs = json.loads(out)["outputs"]
    assert outputs["differ"] == [] and outputs["same"] == []
    assert "report.md" in outputs["same_content"] and "states.parquet" in outputs["same_content"]


def test_an_output_rebuilt_with_a_new_stamp_has_the_same_content(tmp_path):
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    provenance.write_json({"x": 1}, first, {"mjtrial_stamp": 1, "created_utc": "then"})
    provenance.write_json({"x": 1}, second, {"mjtrial_stamp": 1, "created_utc": "now"})
    assert first.read_bytes() != second.read_bytes()
    assert provenance.content_without_stamp(first) == provenance.content_without_stamp(second)
    provenance.write_json({"x": 2}, second, {"mjtrial_stamp": 1, "created_utc": "now"})
    assert provenance.content_without_stamp(first) != provenance.content_without_stamp(second)


def test_bad_input_is_one_line(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    code, _, err = _diff(capsys, tmp_path / "empty", tmp_path / "empty")
    assert code == 2
    assert err.strip().count("\n") == 0 and "seal.json" in err
    sealed = tmp_path / "sealed"  # a run's folder, as far as its seal says
    sealed.mkdir()
    (sealed / "seal.json").write_text(json.dumps({"outputs": {"results/x/states.parquet": "0"}}))
    code, _, err = _diff(capsys, sealed, sealed, "--out", sealed / "diff")
    assert code == 2 and "never writes into a run" in err and not (sealed / "diff").exists()
    code, _, err = _diff(capsys, sealed, sealed, "--level", "5")
    assert code == 2 and "level 5.0: expected in (0, 1)" in err


def _episode(times, values):
    steps = np.round(np.asarray(times) / 0.002).astype(int) - 1
    return {"time": np.asarray(times), "step": steps, "cube_z": np.asarray(values, float)}


def test_first_divergence_is_the_first_shared_time_past_the_tolerance():
    t = np.arange(1, 11) * 0.01
    same = _episode(t, np.linspace(0, 1, 10))
    assert first_divergence(same, same, tolerance=1e-6) is None
    moved = _episode(t, np.r_[np.linspace(0, 1, 10)[:6], np.linspace(0, 1, 10)[6:] + 1e-3])
    d = first_divergence(same, moved, tolerance=1e-6)
    assert d["time"] == pytest.approx(0.07) and d["step"] == [34, 34]
    assert d["quantity"] == "cube_z" and d["difference"] == pytest.approx(1e-3)
    assert first_divergence(same, moved, tolerance=1e-2) is None
    # Another logging grid: only the times both logged are compared.
    half = _episode(t[1::2], np.linspace(0, 1, 10)[1::2] + np.r_[0, 0, 5e-3, 0, 0])
    assert first_divergence(same, half, tolerance=1e-6)["time"] == pytest.approx(0.06)


def _summaries(folder: Path, verdict: str, variant_verdict: str) -> Run:
    """A results folder holding only a summary and a sensitivity study's, for their verdicts."""
    (folder / "analysis").mkdir(parents=True)
    falsifier = {"verdict": verdict}
    paired = {"estimate": 0.3, "low": 0.1, "high": 0.5}
    summary = {"paired_difference": paired, "falsifier": falsifier}
    (folder / "analysis" / "summary.json").write_text(json.dumps(summary))
    variants = {
        "nominal": {"paired_difference": paired, "verdict": verdict},
        "stiff": {"paired_difference": paired, "verdict": variant_verdict},
    }
    (folder / "analysis" / "sensitivity.json").write_text(json.dumps({"variants": variants}))
    return Run(label=folder.name, root=folder, outputs={})


def test_a_study_variant_s_verdict_is_compared_and_gated(tmp_path):
    a = _summaries(tmp_path / "a", "survives", "survives")
    b = _summaries(tmp_path / "b", "survives", "refuted")
    effects = compare_effects(a, b)
    assert set(effects) == {"main", "sensitivity/stiff"}  # the nominal row is the main result
    assert not effects["main"]["changed"] and effects["sensitivity/stiff"]["changed"]
    diff = {"effects": effects}
    assert failures(diff, "verdict") == ["sensitivity/stiff: verdict changed: survives -> refuted"]


def test_every_kind_of_outcome_table_is_a_group(tmp_path):
    outputs = {
        "rollouts/c1.parquet": "",
        "rollouts/c1/shard-00000.parquet": "",
        "variants/v1/rollouts/c1.parquet": "",
        "evaluation/t1/m1/seed-1.parquet": "",
        "evaluation/t1/m1/seed-1/shard-00000.parquet": "",
    }
    groups = rollout_groups(Run(label="x", root=tmp_path, outputs=outputs))
    assert groups == {
        "c1": ("rollouts/c1.parquet", "states.parquet"),
        "v1/c1": ("variants/v1/rollouts/c1.parquet", "states.parquet"),
        "t1/m1/seed-1": ("evaluation/t1/m1/seed-1.parquet", "tasks/t1/states.parquet"),
    }


def test_any_fails_on_a_changed_registered_design_and_names_its_keys():
    same = {"differ": [], "only_a": [], "only_b": []}
    base = {"outputs": same, "conditions": {}}
    unchanged = {"changed": False, "changes": []}
    assert failures({**base, "registration": unchanged}, "any") == []
    changed = {"changed": True, "changes": [{"key": "hypothesis", "a": "x", "b": "y"}]}
    assert failures({**base, "registration": changed}, "any") == [
        "registration: the registered design differs (hypothesis)"
    ]
    one_side = {"changed": True, "changes": []}
    assert failures({**base, "registration": one_side}, "any") == [
        "registration: the registered design differs (registered in one run only)"
    ]
    # the other gates are about outcomes and verdicts, not the design's text
    assert failures({**base, "registration": changed, "effects": {}}, "verdict") == []
