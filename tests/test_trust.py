"""Trust: bad input stops with one line and touches nothing; interrupted runs recover to the
same results; two clean builds give the same data; dirty trees are stamped or refused."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import LINKED, REPO_ROOT, SNAKEMAKE, edit_config, error_lines, run_snakemake

from mjtrial import provenance
from mjtrial.diff import diff_runs, failures, render
from mjtrial.stages.rollout import read_state_values
from mjtrial.task import load_task

pytestmark = pytest.mark.end_to_end

GANTRY_TASK = "tasks/gantry_lift/task.py"
RESULTS = Path("results") / "research_mode"
MODEL = Path("models") / "gantry_gripper" / "gantry_gripper.xml"


def digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and "logs" not in p.parts
    }


def config_case(edit):
    return lambda workdir: edit_config(workdir, edit)


def text_case(path, transform):
    def apply(workdir):
        target = workdir / path
        target.write_text(transform(target.read_text()))

    return apply


def _duplicate_condition(text: str) -> str:
    return text.replace("conditions:\n", "conditions:\n  slow:\n    lift_time: 3.0\n", 1)


def _second_actuator_block(text: str) -> str:
    return text.replace(
        "</actuator>", '  <motor name="extra" joint="gantry_x" gear="1"/>\n  </actuator>'
    )


def _foreign_results(workdir: Path) -> None:
    manifest = workdir / RESULTS / "manifest.json"
    data = json.loads(manifest.read_text())
    data["experiment"] = "another_experiment"
    manifest.write_text(json.dumps(data))


def _model_outside(workdir: Path) -> None:
    outside = workdir.parent / "elsewhere"
    shutil.copytree(workdir / MODEL.parent, outside)
    edit_config(workdir, lambda c: c.update(model=str(outside / "scene.xml")))


def _truncated_manifest(workdir: Path) -> None:
    manifest = workdir / RESULTS / "manifest.json"
    manifest.write_bytes(manifest.read_bytes()[:200])


def _include_outside(workdir: Path) -> None:
    """The scene includes the robot from a folder beside the repository."""
    outside = workdir.parent / "elsewhere"
    outside.mkdir()
    (workdir / MODEL).rename(outside / "robot.xml")
    scene = workdir / MODEL.parent / "scene.xml"
    scene.write_text(
        scene.read_text().replace('file="gantry_gripper.xml"', f'file="{outside / "robot.xml"}"')
    )


def _yaml_bomb(workdir: Path) -> None:
    """Nine levels of nine aliases: a billion values once expanded, a few lines of text."""
    lines = ['a0: &a0 ["lol"]']
    for i in range(1, 10):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    path = workdir / "config" / "config.yaml"
    path.write_text(path.read_text() + "\n".join(["bomb:", *("  " + s for s in lines)]) + "\n")


def _not_utf8(workdir: Path) -> None:
    path = workdir / "config" / "config.yaml"
    lines = path.read_bytes().split(b"\n")
    lines[2] = b"# caf\xff"
    path.write_bytes(b"\n".join(lines))


# (case, how to break a good workdir, what the one-line error must say)
BAD_INPUT = [
    (
        "unknown top-level key",
        config_case(lambda c: c.update(experimnt="x")),
        "experimnt: unknown key",
    ),
    (
        "misspelled nested key",
        config_case(lambda c: c["states"].update(seeed=1)),
        "states.seeed: unknown key",
    ),
    (
        "misspelled condition key",
        config_case(lambda c: c["conditions"]["fast"].update(lift_tme=1)),
        "conditions.fast.lift_tme: unknown key",
    ),
    (
        "wrong type for n",
        config_case(lambda c: c["states"].update(n="many")),
        "states.n: expected integer, got 'many'",
    ),
    ("float n", config_case(lambda c: c["states"].update(n=12.5)), "states.n: expected integer"),
    (
        "n below one",
        config_case(lambda c: c["states"].update(n=0)),
        "states.n: expected >= 1, got 0",
    ),
    (
        "negative lift time",
        config_case(lambda c: c["conditions"]["fast"].update(lift_time=-0.1)),
        "conditions.fast.lift_time: expected > 0, got -0.1",
    ),
    (
        "lift time as text",
        config_case(lambda c: c["conditions"]["slow"].update(lift_time="slow")),
        "conditions.slow.lift_time: expected number",
    ),
    (
        "condition without lift time",
        config_case(lambda c: c["conditions"]["fast"].pop("lift_time")),
        "conditions.fast.lift_time: missing",
    ),
    (
        "confidence above one",
        config_case(lambda c: c["analysis"].update(confidence=1.5)),
        "analysis.confidence: expected < 1, got 1.5",
    ),
    (
        "confidence zero",
        config_case(lambda c: c["analysis"].update(confidence=0)),
        "analysis.confidence: expected > 0, got 0",
    ),
    (
        "too few resamples",
        config_case(lambda c: c["analysis"].update(n_resamples=10)),
        "analysis.n_resamples: expected >= 100",
    ),
    (
        "inverted range",
        config_case(lambda c: c["states"]["ranges"].update(yaw=[0.6, -0.6])),
        "states.ranges.yaw: expected [low, high] with low < high",
    ),
    (
        "negative mass",
        config_case(lambda c: c["states"]["ranges"].update(mass=[-0.1, 0.6])),
        "states.ranges.mass[0]: expected > 0",
    ),
    (
        "same development and evaluation seed",
        config_case(lambda c: c["states"].update(development_seed=2026)),
        "states.development_seed: expected a seed other than states.seed",
    ),
    (
        "falsifier names an unknown condition",
        config_case(lambda c: c["design"]["falsifier"].update(baseline="medium")),
        "design.falsifier.baseline: expected one of the conditions",
    ),
    (
        "falsifier names an unknown statistic",
        config_case(lambda c: c["design"]["falsifier"].update(statistic="median")),
        "design.falsifier.statistic: expected one of ['paired_difference']",
    ),
    (
        "mass bands do not cover the masses",
        config_case(lambda c: c["analysis"]["bands"].update(mass=[0.1, 0.3, 0.6])),
        "analysis.bands.mass: expected edges covering",
    ),
    (
        "zero logging rate",
        config_case(lambda c: c["recording"].update(rate_hz=0)),
        "recording.rate_hz: expected > 0",
    ),
    (
        "duplicate condition name",
        text_case("config/config.yaml", _duplicate_condition),
        "conditions.slow: duplicate key",
    ),
    (
        "YAML syntax error",
        text_case("config/config.yaml", lambda t: t + "\nstates: [unclosed\n"),
        "not valid YAML",
    ),
    (
        "missing model file",
        config_case(lambda c: c.update(model="models/nowhere/scene.xml")),
        "model: expected an existing model file, got 'models/nowhere/scene.xml'",
    ),
    (
        "malformed model file",
        text_case(MODEL, lambda t: t.replace("</worldbody>", "", 1)),
        "model: models/gantry_gripper/scene.xml: MuJoCo could not compile the model",
    ),
    (
        "model without a cube",
        text_case(MODEL, lambda t: t.replace('<body name="cube"', '<body name="box"')),
        "expected a body named 'cube'",
    ),
    (
        "model with a fifth actuator",
        text_case(MODEL, _second_actuator_block),
        "expected 4 actuators (x, y, z, gripper), found 5",
    ),
    (
        "results of another experiment",
        _foreign_results,
        "written by experiment 'another_experiment'",
    ),
    (
        "NaN lift time",
        text_case("config/config.yaml", lambda t: t.replace("lift_time: 0.15", "lift_time: .nan")),
        "conditions.fast.lift_time: expected a finite number, got nan",
    ),
    (
        "infinite confidence",
        text_case(
            "config/config.yaml", lambda t: t.replace("confidence: 0.95", "confidence: .inf")
        ),
        "analysis.confidence: expected a finite number, got inf",
    ),
    (
        "n written as a float",
        text_case("config/config.yaml", lambda t: t.replace("  n: 12\n", "  n: 12.0\n")),
        "states.n: expected integer, got 12.0",
    ),
    (
        "n beyond its bound",
        config_case(lambda c: c["states"].update(n=1_000_000_000)),
        "states.n: expected <= 1000000, got 1000000000",
    ),
    (
        "lift time beyond its bound",
        config_case(lambda c: c["conditions"]["slow"].update(lift_time=100)),
        "conditions.slow.lift_time: expected <= 10, got 100",
    ),
    (
        "resamples beyond their bound",
        config_case(lambda c: c["analysis"].update(n_resamples=10**9)),
        "analysis.n_resamples: expected <= 1000000",
    ),
    (
        "first k beyond n",
        config_case(lambda c: c["analysis"].update(first_k=13)),
        "analysis.first_k: expected at most states.n (12)",
    ),
    (
        "experiment '..'",
        config_case(lambda c: c.update(experiment="..")),
        "experiment: expected a name matching",
    ),
    (
        "experiment '.'",
        config_case(lambda c: c.update(experiment=".")),
        "experiment: expected a name matching",
    ),
    (
        "experiment with a slash",
        config_case(lambda c: c.update(experiment="a/b")),
        "experiment: expected a name matching",
    ),
    (
        "model outside the repository",
        _model_outside,
        "model: expected a file inside the repository",
    ),
    (
        "model timestep coarser than the protocol's step",
        text_case(MODEL, lambda t: t.replace('timestep="0.002"', 'timestep="0.1"')),
        "timestep 0.1 s; expected at most 0.01 s",
    ),
    (
        "unstable model",
        text_case(
            MODEL, lambda t: t.replace('impratio="10"/>', 'impratio="10" gravity="0 0 -1e15"/>')
        ),
        "unstable: the nominal episode under condition 'fast' stops at step 1 with mjWARN_BADQACC",
    ),
    (
        "unclosed XML tag",
        text_case(MODEL, lambda t: t.replace("</body>\n", "", 1)),
        "XML_ERROR_MISMATCHED_ELEMENT ErrorID=14 (0xe) Line number=",
    ),
    (
        "variant with an unknown option",
        config_case(lambda c: c.update(variants={"x": {"option": {"timestepp": 0.001}}})),
        "variants.x.option.timestepp: unknown option; expected one of",
    ),
    (
        "variant of an element the model lacks",
        config_case(
            lambda c: c.update(variants={"x": {"geom": {"left_pads": {"friction": [1, 0, 0]}}}})
        ),
        "variants.x.geom.left_pads: the model has no geom of that name",
    ),
    (
        "variant with a wrongly shaped friction",
        config_case(
            lambda c: c.update(variants={"x": {"geom": {"left_pad": {"friction": [0.6, 0.003]}}}})
        ),
        "variants.x.geom.left_pad.friction: expected 3 numbers, got 2",
    ),
    (
        "variant with an unknown integrator",
        config_case(lambda c: c.update(variants={"x": {"option": {"integrator": "RK5"}}})),
        "variants.x.option.integrator: expected one of Euler, RK4, implicit, implicitfast",
    ),
    (
        "variant with a zero timestep",
        config_case(lambda c: c.update(variants={"x": {"option": {"timestep": 0}}})),
        "variants.x.option.timestep: expected a positive number, got 0",
    ),
    (
        "variant coarser than the protocol's step",
        config_case(lambda c: c.update(variants={"x": {"option": {"timestep": 0.02}}})),
        "variants.x.option.timestep: timestep 0.02 s; expected at most 0.01 s",
    ),
    (
        "sweep of an unknown parameter",
        config_case(lambda c: c["sweep"].update(parameter="speed")),
        "sweep.parameter: expected one of ['lift_time'",
    ),
    (
        "sweep of two values",
        config_case(lambda c: c["sweep"].update(values=[0.15, 1.5])),
        "sweep.values: expected at least 3 items",
    ),
    (
        "sweep value out of range",
        config_case(lambda c: c["sweep"].update(values=[0.15, 1.5, 20])),
        "sweep.values[2]: expected <= 10, got 20",
    ),
    # variants that would inflate "survives N of M" (survey 2, case 8)
    (
        "variant named as the committed model",
        config_case(lambda c: c.update(variants={"nominal": {"option": {"integrator": "RK4"}}})),
        "variants.nominal: 'nominal' is reserved for the model as committed",
    ),
    (
        "variant that changes nothing",
        config_case(lambda c: c.update(variants={"same": {"option": {"timestep": 0.002}}})),
        "variants.same: changes nothing: the edited model simulates as the committed one",
    ),
    (
        "two identical variants",
        config_case(
            lambda c: c.update(
                variants={
                    "rk4": {"option": {"integrator": "RK4"}},
                    "rk4_again": {"option": {"integrator": "RK4"}},
                }
            )
        ),
        "variants.rk4_again: the same simulation as variants.rk4; expected each variant once",
    ),
    # a corrupt manifest is named so, not as another experiment's (survey 2, case 4)
    (
        "truncated manifest",
        _truncated_manifest,
        "results/research_mode/manifest.json: corrupt (JSONDecodeError",
    ),
    # the model is everything it loads (survey 2, case 1)
    (
        "model including a file outside the repository",
        _include_outside,
        "model: models/gantry_gripper/scene.xml loads ../elsewhere/robot.xml, outside the "
        "repository",
    ),
    # the work a config may cost, bounded before any (survey 2, case 12)
    (
        "variant timestep of a microsecond",
        config_case(lambda c: c.update(variants={"fine": {"option": {"timestep": 1e-6}}})),
        "variants.fine.option.timestep: timestep 1e-06 s gives 2,850,000 steps per episode",
    ),
    (
        "model timestep of a microsecond",
        text_case(MODEL, lambda t: t.replace('timestep="0.002"', 'timestep="0.000001"')),
        "model: models/gantry_gripper/scene.xml: timestep 1e-06 s gives 2,850,000 steps",
    ),
    (
        "a rollout job per state",
        config_case(lambda c: (c["states"].update(n=20000), c["rollout"].update(shard_size=1))),
        "rollout.shard_size: 1 states per shard make 520,000 rollout jobs for 20,000 states",
    ),
    (
        "a hold shorter than a step",
        config_case(lambda c: c["conditions"]["slow"].update(hold_time=0.0004)),
        "conditions.slow.hold_time: a hold_time of 0.0004 s is 0 steps of 0.002 s",
    ),
    (
        "a logging rate that logs nothing",
        config_case(lambda c: c["recording"].update(rate_hz=0.1)),
        "recording.rate_hz: 0.1 Hz logs one step every 10 s",
    ),
    (
        "YAML bomb",
        _yaml_bomb,
        "config/config.yaml: expands to more than 100000 values through YAML aliases",
    ),
    (
        "config not UTF-8",
        _not_utf8,
        "config/config.yaml: not UTF-8 text (byte 0xff on line 3)",
    ),
]


def copy_of(built: Path, workdir: Path) -> Path:
    """A copy of the built experiment, its large model folders that no case reads (conftest's
    `LINKED`: 43 MB of robosuite meshes) linked, not copied."""
    linked = {built / rel for rel in LINKED}
    shutil.copytree(
        built,
        workdir,
        symlinks=True,
        ignore=lambda folder, names: [n for n in names if Path(folder, n) in linked],
    )
    for rel in LINKED:
        (workdir / rel).symlink_to(REPO_ROOT / rel, target_is_directory=True)
    return workdir


@pytest.mark.parametrize(("case", "breaks", "message"), BAD_INPUT, ids=[c[0] for c in BAD_INPUT])
def test_bad_input_stops_with_one_line_and_touches_nothing(built, tmp_path, case, breaks, message):
    workdir = copy_of(built, tmp_path / "copy")
    breaks(workdir)
    before = digest(workdir / "results")
    proc = run_snakemake(workdir, check=False)
    assert proc.returncode != 0
    lines = error_lines(proc)
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("Config error: ")
    assert message in lines[0], lines[0]
    assert digest(workdir / "results") == before


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda t: t.drop_columns(["yaw"]), r"states\.parquet: missing column\(s\) \['yaw'\]"),
        (
            lambda t: t.set_column(
                4, "mass", pa.array([np.nan] + t.column("mass").to_pylist()[1:])
            ),
            r"states\.parquet: column 'mass' has non-finite values \(first at state 0\)",
        ),
    ],
    ids=["missing column", "NaN mass"],
)
def test_bad_states_table_is_named_in_one_line(built, tmp_path, damage, message):
    path = tmp_path / "states.parquet"
    shutil.copy(built / RESULTS / "states.parquet", path)
    pq.write_table(damage(pq.read_table(path)), path)
    with pytest.raises(ValueError, match=message) as err:
        read_state_values(path, load_task(GANTRY_TASK, repo_root=REPO_ROOT))
    assert "\n" not in str(err.value)


def _data(folder: Path) -> dict[str, object]:
    """What must be identical between two builds: tables' data, summaries without stamps."""
    out: dict[str, object] = {}
    for path in sorted(folder.rglob("*.parquet")):
        out[str(path.relative_to(folder))] = pq.read_table(path).replace_schema_metadata(None)
    for path in sorted(folder.rglob("*.json")):
        rel = path.relative_to(folder)
        if rel.parts[0] == "source" or rel.name == "ro-crate-metadata.json":
            continue  # the crate's copy of the code; the crate holds the jobs' times and stamps
        data = json.loads(path.read_text())
        data.pop("provenance", None)
        data.pop("stamps", None)  # the manifest's copies of every stamp
        if path.name == "seal.json":
            data.pop("outputs")  # sha256 of stamped files, whose stamps hold their time
            data.pop("registration", None)  # the same, of the registration
        if path.name == "registration.json":  # each build registers anew: the design, no time
            data = {k: data["current"][k] for k in ("design", "design_sha256", "plan")}
        if path.name == "manifest.json" and "registration" in data:
            data["registration"] = {
                k: v
                for k, v in data["registration"].items()
                if k not in ("sha256", "registered_utc")  # the file's hash holds its time
            }
        out[str(rel)] = data
    return out


def assert_same_data(first_dir: Path, second_dir: Path) -> None:
    first, second = _data(first_dir), _data(second_dir)
    assert first.keys() == second.keys()
    for name, value in first.items():
        if isinstance(value, pa.Table):
            assert value.equals(second[name]), name
        else:
            assert value == second[name], name


def test_two_clean_builds_give_identical_data(built, tmp_path):
    workdir = tmp_path / "again"
    shutil.copytree(built, workdir)
    shutil.rmtree(workdir / "results")
    shutil.rmtree(workdir / ".snakemake", ignore_errors=True)  # a clean build: no records
    run_snakemake(workdir)
    assert_same_data(built / RESULTS, workdir / RESULTS)
    # issue 42 item 13: the gate failed every pair of honest rebuilds, whose manifest and
    # report differ only by when the design was registered (a record, as a stamp is)
    diff = diff_runs(built / RESULTS, workdir / RESULTS)
    assert failures(diff, "any") == [], render(diff)
    assert diff["outputs"]["differ"] == []
    assert {"manifest.json", "report.md"} <= set(diff["outputs"]["same_content"])


def test_killed_run_recovers_to_the_uninterrupted_results(built, tmp_path):
    """SIGKILL snakemake part-way through the rollouts, then the README's recovery command."""
    workdir = tmp_path / "killed"
    shutil.copytree(built, workdir)
    shutil.rmtree(workdir / "results")
    shutil.rmtree(workdir / ".snakemake", ignore_errors=True)
    proc = subprocess.Popen(
        [SNAKEMAKE, "-c2"],
        cwd=workdir,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    rollout_log = workdir / RESULTS / "logs" / "rollout_fast_00000.log"  # the first shard's
    deadline = time.monotonic() + 120
    while not rollout_log.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.02)
    assert proc.poll() is None, "the run finished before it could be interrupted"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    # Nothing under a final name is truncated: whatever exists carries a readable stamp (a
    # folder of recordings: every .rrd in it). Hidden names are the writers' temporary files.
    results = workdir / RESULTS
    for path in results.rglob("*"):
        rel = path.relative_to(results)
        if any(part.startswith(".") for part in rel.parts) or rel.parts[0] == "logs":
            continue
        if provenance.is_recording_folder(path):
            assert provenance.read_stamp(path)["rule"].startswith("rollout")
        elif path.is_file() and path.suffix != ".rbl":
            provenance.read_stamp(path)
    # The README's recovery command: release the dead run's lock, redo what it left incomplete.
    run_snakemake(workdir, "--unlock")
    run_snakemake(workdir, "--rerun-incomplete")
    assert_same_data(built / RESULTS, workdir / RESULTS)


def _git(workdir: Path, *args: str) -> None:
    env = {
        **os.environ,
        "GIT_AUTHOR_NAME": "t",
        "GIT_AUTHOR_EMAIL": "t@example.invalid",
        "GIT_COMMITTER_NAME": "t",
        "GIT_COMMITTER_EMAIL": "t@example.invalid",
        "GIT_CONFIG_GLOBAL": os.devnull,
        "GIT_CONFIG_NOSYSTEM": "1",
    }
    subprocess.run(["git", *args], cwd=workdir, check=True, capture_output=True, env=env)


def test_dirty_tree_warns_once_and_require_clean_refuses(built, tmp_path):
    workdir = tmp_path / "repo"
    shutil.copytree(built, workdir)
    (workdir / ".gitignore").write_text("results/\n.snakemake/\n")
    _git(workdir, "init", "-q", "-b", "main")
    _git(workdir, "add", "-A")
    _git(workdir, "commit", "-q", "-m", "experiment")
    clean = run_snakemake(workdir, "-n")
    assert "uncommitted changes" not in clean.stderr
    edit_config(workdir, lambda c: c["analysis"].update(n_resamples=700))
    dirty = run_snakemake(workdir)
    assert dirty.stderr.count("Warning: the repository has uncommitted changes") == 1
    stamp = provenance.read_stamp(workdir / RESULTS / "analysis" / "summary.json")
    assert stamp["git"]["dirty"] is True and len(stamp["git"]["diff_sha256"]) == 64
    before = digest(workdir / "results")
    edit_config(workdir, lambda c: c["provenance"].update(require_clean=True))
    refused = run_snakemake(workdir, check=False)
    assert refused.returncode != 0
    assert "provenance.require_clean is true and the repository has uncommitted changes" in (
        refused.stderr
    )
    assert digest(workdir / "results") == before


def test_development_states_are_built_alone_and_disjoint(built, tmp_path):
    workdir = tmp_path / "dev"
    shutil.copytree(built, workdir)
    run_snakemake(workdir, "dev")
    task = load_task(GANTRY_TASK, repo_root=REPO_ROOT)
    dev = read_state_values(workdir / RESULTS / "development" / "states.parquet", task)
    evaluation = read_state_values(workdir / RESULTS / "states.parquet", task)
    assert len(dev["state_id"]) == len(evaluation["state_id"]) == 12

    def rows(values):
        return set(zip(*(values[p] for p in ("dx", "dy", "yaw", "mass")), strict=True))

    assert not rows(dev) & rows(evaluation)
    assert (
        provenance.read_stamp(workdir / RESULTS / "development" / "states.parquet")["rule"]
        == "states:development"
    )
