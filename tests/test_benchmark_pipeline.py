"""The benchmark from nothing (`snakemake -c2 --configfile config/benchmark.yaml`), small: the
report is built and a second run does nothing; adding a seed runs only that seed's training and
evaluation, and what reads every seed; the fixed method's outcomes equal the gantry's plain
`mj_step` reference on the same evaluation states; both overall rates in the summary equal
sums done here from the evaluation tables. The ES-trained MLP runs one policy file per training
seed on the cart-pole only: its IQM is over those files, the gantry says it was not run, and a
file edited after the run fails verify naming the file."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, run_snakemake

from mjtrial import provenance
from mjtrial.cli import main
from mjtrial.files.layout import BenchmarkLayout

pytestmark = pytest.mark.end_to_end

CONFIG = "config/benchmark.yaml"
LAYOUT = BenchmarkLayout.of("benchmark")
N_STATES = 8
CARTPOLE = "config/cartpole_latency.yaml"
CARTPOLE_SHARD = 3
CLOSEST_K = 3
MLP = "policies/cartpole_mlp/seed-{}.onnx"


def edit_yaml(path: Path, edit) -> None:
    data = yaml.safe_load(path.read_text())
    edit(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def small(config):
    bench = config["benchmark"]
    bench["seeds"] = [1, 2, 3]
    bench["result"] = "development"
    # the least budget that tunes: 6 x 4 for one generation, 3 x 8 for the finalists
    bench["methods"]["tuned"]["budget"] = 48
    bench["methods"]["tuned"]["episodes_per_candidate"] = 4
    bench["analysis"]["n_resamples"] = 200
    bench["closest_calls"] = CLOSEST_K
    # the MLP's checkpoints of the 3 seeds: the glob names one file per seed
    bench["methods"]["mlp_es"]["tasks"]["cartpole_latency"]["policy"] = MLP.format("[1-3]")


@pytest.fixture(scope="module")
def bench(tmp_path_factory) -> Path:
    workdir = copy_workflow(tmp_path_factory.mktemp("benchmark"))
    for experiment in ("config/config.yaml", "config/cartpole_latency.yaml"):
        edit_yaml(workdir / experiment, lambda c: c["states"].update(n=N_STATES))
        # the experiment's own "first states only" analysis (no benchmark's): at most n
        edit_yaml(workdir / experiment, lambda c: c["analysis"].update(first_k=N_STATES))
    # the cart-pole's evaluations in shards of 3 states (3, 3, 2), the gantry's in one
    edit_yaml(workdir / CARTPOLE, lambda c: c["rollout"].update(shard_size=CARTPOLE_SHARD))
    edit_yaml(workdir / CONFIG, small)
    run_snakemake(workdir, "--configfile", CONFIG)
    return workdir


def planned(workdir: Path, *args: str) -> dict[str, int]:
    out = run_snakemake(workdir, "-n", "--configfile", CONFIG, *args).stdout
    table = out.split("Job stats:")[1] if "Job stats:" in out else ""
    return {
        m[1]: int(m[2])
        for m in re.finditer(r"^(\w+)\s+(\d+)$", table, re.MULTILINE)
        if m[1] != "total"
    }


def test_the_benchmark_builds_its_report_and_a_second_run_does_nothing(bench):
    report = (bench / LAYOUT.report).read_text()
    assert "Development decision" in report and "## Overall success rates" in report
    assert "**The budgets differ.**" in report
    assert "![Performance profiles](figures/performance_profile.png)" in report
    for figure in LAYOUT.benchmark_figure_files():
        assert provenance.read_stamp(bench / figure)["rule"] == "benchmark_report"
    assert planned(bench) == {}


def test_adding_a_seed_runs_only_its_training_and_evaluation_and_what_reads_every_seed(bench):
    def policy(pattern):
        def edit(c):
            c["benchmark"]["methods"]["mlp_es"]["tasks"]["cartpole_latency"]["policy"] = pattern

        return edit

    edit_yaml(bench / CONFIG, lambda c: c["benchmark"]["seeds"].append(4))
    edit_yaml(bench / CONFIG, policy(MLP.format("[1-4]")))
    try:
        jobs = planned(bench)
    finally:
        edit_yaml(bench / CONFIG, lambda c: c["benchmark"]["seeds"].remove(4))
        edit_yaml(bench / CONFIG, policy(MLP.format("[1-3]")))
    # 2 tasks x 2 methods for seed 4 and the MLP's fourth file on the cart-pole (the gantry's
    # evaluations in 1 shard, the cart-pole's in 3), then what reads every seed, seal and crate
    assert jobs == {
        "train": 5,
        "evaluate": 2 * 1 + 3 * 3,
        "evaluate_gather": 5,
        "benchmark_summary": 1,
        "closest_calls": 1,
        "benchmark_report": 1,
        "benchmark_seal": 1,
        "benchmark_crate": 1,
        "all": 1,
    }


def test_the_fixed_method_equals_the_plain_reference_on_the_evaluation_states(bench):
    from gantry_lift.model_spec import ModelSpec
    from gantry_lift.protocol import PROTOCOL
    from gantry_lift.simulate import reference_episode
    from gantry_lift.states import states_from_table

    from mjtrial.sim.physics import load_model

    model = load_model(REPO_ROOT / "models" / "gantry_gripper" / "scene.xml")
    states = states_from_table(pq.read_table(bench / LAYOUT.task("gantry_lift").states))
    z = ModelSpec.of(model).state_cube_z
    expected = [
        bool(reference_episode(model, s, lift_time=0.15)[0][-1, z] > PROTOCOL.success_height)
        for s in states
    ]
    for seed in (1, 2, 3):
        table = pq.read_table(bench / LAYOUT.evaluation("gantry_lift", "as_designed", seed))
        assert table.column("state_id").to_pylist() == [s.state_id for s in states]
        assert table.column("success").to_pylist() == expected


def test_an_evaluation_in_shards_equals_one_over_every_state(bench, tmp_path):
    from mjtrial.stages.evaluate import evaluate_method

    task = LAYOUT.task("cartpole_latency")
    shards = sorted(
        (bench / LAYOUT.evaluation("cartpole_latency", "tuned", 2))
        .with_suffix("")
        .glob("*.parquet")
    )
    assert len(shards) == 3
    whole = evaluate_method(
        states=bench / task.states,
        parameters=bench / LAYOUT.parameters("cartpole_latency", "tuned", 2),
        model_file=bench / "tasks" / "cartpole_latency" / "cartpole.xml",
        evaluate_slice={
            "task": "tasks/cartpole_latency/task.py",
            "failure_taxonomy": {"fall_angle": 0.5},
        },
        output=tmp_path / "whole.parquet",
        repo_root=bench,
    )
    gathered = pq.read_table(bench / LAYOUT.evaluation("cartpole_latency", "tuned", 2))
    assert gathered.replace_schema_metadata(None).equals(whole.replace_schema_metadata(None))
    assert gathered.num_rows == N_STATES


def test_a_deleted_evaluation_shard_is_rebuilt_with_what_reads_it(bench, tmp_path):
    """Trust survey 3, case 8: a deleted evaluation shard (read by its gather only) was never
    rebuilt: `snakemake -c2` had nothing to do while verify said missing."""
    workdir = tmp_path / "copy"
    shutil.copytree(bench, workdir, symlinks=True)
    (workdir / LAYOUT.evaluation_shard("cartpole_latency", "tuned", 2, "00001")).unlink()
    assert planned(workdir) == {
        "evaluate": 1,
        "evaluate_gather": 1,
        "benchmark_summary": 1,
        "closest_calls": 1,
        "benchmark_report": 1,
        "benchmark_seal": 1,
        "benchmark_crate": 1,
        "all": 1,
    }


def test_both_overall_rates_equal_sums_over_the_evaluation_tables(bench):
    summary = json.loads((bench / LAYOUT.summary).read_text())
    for method in ("as_designed", "tuned"):
        for seed in (1, 2, 3):
            rates = {
                task: pq.read_table(bench / LAYOUT.evaluation(task, method, seed))
                .column("success")
                .to_numpy()
                for task in ("gantry_lift", "cartpole_latency")
            }
            episode_mean = sum(r.sum() for r in rates.values()) / sum(
                r.size for r in rates.values()
            )
            task_mean = np.mean([r.mean() for r in rates.values()])
            got = summary["overall"][method]
            assert got["episode_mean"]["per_seed"][str(seed)]["estimate"] == pytest.approx(
                episode_mean
            )
            assert got["task_mean"]["per_seed"][str(seed)]["estimate"] == pytest.approx(task_mean)


def test_every_training_read_the_development_states_only(bench):
    for task in ("gantry_lift", "cartpole_latency"):
        development = bench / LAYOUT.task(task).development_states
        for seed in (1, 2, 3):
            stamp = provenance.read_stamp(bench / LAYOUT.parameters(task, "tuned", seed))
            recorded = stamp["inputs"]["development_states"]
            assert recorded["path"] == development.relative_to(bench).as_posix()
            assert recorded["sha256"] == provenance.file_sha256(development)


def cli(workdir: Path, *args: str) -> subprocess.CompletedProcess:
    """`mjtrial ARGS` run from `workdir`, in this process: the command's own `main`, its exit
    code and what it printed (a subprocess would import the package again for each call; the
    archive's test below runs the unpacked package's command in one)."""
    out, err = io.StringIO(), io.StringIO()
    before = Path.cwd()
    os.chdir(workdir)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(list(args))
    finally:
        os.chdir(before)
    return subprocess.CompletedProcess(["mjtrial", *args], code, out.getvalue(), err.getvalue())


def verify(workdir: Path):
    """`mjtrial verify --config` without re-simulation (tested on its own below): a few
    seconds less each."""
    return cli(workdir, "verify", "--config", CONFIG, "--resimulate", "0")


def test_verify_passes_the_benchmark_as_built(bench):
    done = verify(bench)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "verified: results/benchmark:" in done.stdout and " 0 problems" in done.stdout


def test_the_seal_lists_every_output_and_the_crate_validates_offline(bench, tmp_path, monkeypatch):
    """The seal lists every file of the results folder (but the logs, itself, the crate and
    its copy of the sources) with its sha256 of now; the crate describes a benchmark, each
    task's states as a job of its own, and the validator finds no REQUIRED issue offline."""
    import socket

    from mjtrial.crate import validation

    results = bench / LAYOUT.root
    expected = {
        file.relative_to(bench).as_posix(): provenance.file_sha256(file)
        for file in results.rglob("*")
        if file.is_file()
        and file.relative_to(results).parts[0] not in ("logs", "source")
        and file.name not in ("seal.json", "ro-crate-metadata.json")
    }
    assert json.loads((bench / LAYOUT.seal).read_text())["outputs"] == expected
    graph = json.loads((bench / LAYOUT.crate).read_text())["@graph"]
    entities = {e["@id"]: e for e in graph}
    assert entities["#run"]["name"] == "Run of the mjtrial workflow: benchmark benchmark"
    assert "--configfile config/benchmark.yaml" in entities["#run"]["description"]
    assert entities["./"]["description"].startswith("Does tuning a task's protocol parameters")
    for task in ("gantry_lift", "cartpole_latency"):
        for kind, states in (
            ("evaluation", LAYOUT.task(task).states),
            ("development", LAYOUT.task(task).development_states),
        ):
            job = entities[f"#job/states:{kind}:{task}"]
            assert job["result"] == {"@id": states.relative_to(LAYOUT.root).as_posix()}
    # every output in the crate with the sha256 the seal lists
    for path, sha in expected.items():
        assert entities[Path(path).relative_to(LAYOUT.root).as_posix()]["sha256"] == sha

    def no_network(*args, **kwargs):
        raise AssertionError("the validator opened a connection")

    monkeypatch.setattr(socket.socket, "connect", no_network)
    findings = validation.validate(results, cache_path=tmp_path / "cache" / "http")
    assert findings == [], "\n".join(f.line() for f in findings)


def test_verify_names_an_edited_report_an_edited_crate_and_a_missing_seal(bench, tmp_path):
    """Nothing after the report records its sha256 but the seal, and nothing after the seal
    but the crate."""
    workdir = tmp_path / "copy"
    shutil.copytree(bench, workdir, symlinks=True)
    report = workdir / LAYOUT.report
    text = report.read_text()
    report.write_text(text.replace("Development decision", "Development Decision", 1))
    done = verify(workdir)
    assert done.returncode == 1
    assert f"{LAYOUT.report.as_posix()}: changed since it was sealed" in done.stdout
    report.write_text(text)
    crate = workdir / LAYOUT.crate
    document = crate.read_text()
    crate.write_text(document.replace("Run of the mjtrial workflow", "Run of another workflow"))
    done = verify(workdir)
    assert done.returncode == 1
    assert f"{LAYOUT.crate.as_posix()}: #run: name (file -> recomputed)" in done.stdout
    crate.write_text(document)
    assert verify(workdir).returncode == 0
    (workdir / LAYOUT.seal).unlink()
    done = verify(workdir)
    assert done.returncode == 1 and f"{LAYOUT.seal.as_posix()}: missing" in done.stdout


def test_the_benchmarks_archive_unpacked_elsewhere_verifies_and_has_nothing_to_do(bench, tmp_path):
    import sys
    import zipfile

    from mjtrial import cli

    archive = tmp_path / "benchmark.zip"
    args = ["crate", str(bench / LAYOUT.root), "--zip", str(archive), "--repo-root", str(bench)]
    assert cli.main([*args, "--config", str(bench / CONFIG)]) == 0
    there = tmp_path / "elsewhere"
    with zipfile.ZipFile(archive) as z:
        z.extractall(there)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(there / "src")  # the unpacked package, not this one

    def run(*command: str) -> str:
        done = subprocess.run(
            [sys.executable, "-m", *command], cwd=there, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stdout + done.stderr
        return done.stdout + done.stderr

    assert "verified: results/benchmark:" in run("mjtrial.cli", "verify", "--config", CONFIG)
    assert "Nothing to be done" in run("snakemake", "-c2", "-n", "--configfile", CONFIG)


def test_verify_fails_a_training_that_read_the_evaluation_states(bench, tmp_path):
    """A training job pointed at the evaluation states (its stage refuses them, so the stamp is
    forged here as a job that got past it would have written it)."""
    from mjtrial.stages.stamping import make_stage_stamp

    workdir = tmp_path / "copy"
    shutil.copytree(bench, workdir, symlinks=True)
    parameters = workdir / LAYOUT.parameters("gantry_lift", "tuned", 2)
    record = json.loads(parameters.read_text())
    old = provenance.read_stamp(parameters)
    evaluation = LAYOUT.task("gantry_lift").states
    stamp = make_stage_stamp(
        old["rule"],
        old["config_slice"],
        {"development_states": workdir / evaluation},
        repo_root=workdir,
    )
    provenance.write_json(record, parameters, stamp)
    done = verify(workdir)
    assert done.returncode == 1, done.stdout + done.stderr
    assert (
        f"{LAYOUT.parameters('gantry_lift', 'tuned', 2).as_posix()}: read "
        f"'{evaluation.as_posix()}' as development_states, expected "
        f"{LAYOUT.task('gantry_lift').development_states.as_posix()}"
    ) in done.stdout


def test_verify_fails_development_states_that_hold_evaluation_states(bench, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(bench, workdir, symlinks=True)
    task = LAYOUT.task("cartpole_latency")
    development = workdir / task.development_states
    stamp = provenance.read_stamp(development)
    provenance.write_parquet(pq.read_table(workdir / task.states), development, stamp)
    done = verify(workdir)
    assert done.returncode == 1
    assert f"{task.development_states.as_posix()}: {N_STATES} state(s) also among" in done.stdout
    assert "changed since it was read" in done.stdout  # every training read other states


def test_the_solvability_check_runs_the_corners_under_the_reference_and_lists_failures(bench):
    from gantry_lift.model_spec import ModelSpec
    from gantry_lift.protocol import PROTOCOL
    from gantry_lift.simulate import reference_episode
    from gantry_lift.states import InitialState

    from mjtrial.sim.physics import load_model

    table = pq.read_table(bench / LAYOUT.solvability("gantry_lift")).to_pylist()
    assert len(table) == 16 and {r["probe"] for r in table} == {"corners"}
    model = load_model(REPO_ROOT / "models" / "gantry_gripper" / "scene.xml")
    z = ModelSpec.of(model).state_cube_z
    for i, r in enumerate(table):  # the reference controller: the slow lift (1.5 s)
        state = InitialState(i, r["dx"], r["dy"], r["yaw"], r["mass"])
        physics, _ = reference_episode(model, state, lift_time=1.5)
        assert r["success"] == bool(physics[-1, z] > PROTOCOL.success_height)
    summary = json.loads((bench / LAYOUT.summary).read_text())["solvability"]
    assert summary["gantry_lift"]["n"] == 16
    assert summary["gantry_lift"]["reference"] == {"lift_time": 1.5}
    unsolved = [r for r in table if not r["success"]]
    assert len(summary["gantry_lift"]["unsolved"]) == len(unsolved)
    report = (bench / LAYOUT.report).read_text()
    assert f"**gantry_lift**: {16 - len(unsolved)} of 16 probe states (corners" in report
    assert summary["cartpole_latency"]["n"] == 32  # five state parameters: 2^5 corners


def _margins_by_hand(bench: Path, task: str) -> list[tuple[float, bool, str, int, int]]:
    """(margin, success, method, seed, state) of every candidate episode, from the evaluation
    tables and the tasks' success tests as their modules state them (the fixed method ran the
    same episodes under every seed: its first seed's; the MLP's seeds are files of their own,
    run on the cart-pole only)."""
    from gantry_lift.protocol import PROTOCOL

    rows = []
    methods = (
        ("as_designed", "tuned", "mlp_es")
        if task == "cartpole_latency"
        else ("as_designed", "tuned")
    )
    for method in methods:
        for seed in (1,) if method == "as_designed" else (1, 2, 3):
            table = pq.read_table(bench / LAYOUT.evaluation(task, method, seed)).to_pylist()
            for r in table:
                if task == "gantry_lift":  # success: final height above the success height
                    margin = r["final_height"] - PROTOCOL.success_height
                else:  # success: below 1 of the limits over the judged second
                    margin = 1.0 - r["peak_limit_fraction"]
                rows.append((margin, r["success"], method, seed, r["state_id"]))
    return rows


@pytest.mark.parametrize("task", ["gantry_lift", "cartpole_latency"])
def test_the_closest_calls_are_the_smallest_and_largest_margins(bench, task):
    rows = _margins_by_hand(bench, task)
    assert all((m > 0) == s for m, s, *_ in rows if m != 0)  # the margin's sign is success
    closest = sorted((r for r in rows if r[1]), key=lambda r: r[0])[:CLOSEST_K]
    rest = [r for r in rows if r not in closest]
    highest = sorted(rest, key=lambda r: -r[0])[:CLOSEST_K]
    table = [r for r in pq.read_table(bench / LAYOUT.closest_calls_table).to_pylist()]
    got = [r for r in table if r["task"] == task]
    expected = [("closest success", r) for r in closest] + [("highest score", r) for r in highest]
    assert [(r["kind"], r["method"], r["seed"], r["state_id"]) for r in got] == [
        (kind, method, seed, state) for kind, (_, _, method, seed, state) in expected
    ]
    assert [r["margin"] for r in got] == pytest.approx([r[0] for _, r in expected], abs=1e-12)


def test_the_closest_calls_replay_file_holds_each_episode_as_its_table_scored_it(bench):
    from mjtrial.recording import list_recordings

    table = pq.read_table(bench / LAYOUT.closest_calls_table).to_pylist()
    recordings = list_recordings(bench / LAYOUT.closest_calls)
    assert recordings[0]["recording_id"] == "closest_calls"
    assert recordings[0]["provenance"]["rule"] == "closest_calls"
    by_id = {r["recording_id"]: r for r in recordings[1:]}
    assert sorted(by_id) == sorted(r["recording_id"] for r in table)
    assert len(table) == 2 * 2 * CLOSEST_K
    for row in table:
        recorded = by_id[row["recording_id"]]
        assert recorded["state_id"] == row["state_id"] and recorded["success"] == row["success"]
        evaluation = pq.read_table(
            bench / LAYOUT.evaluation(row["task"], row["method"], row["seed"])
        ).to_pylist()[row["state_id"]]
        measure = "final_height" if row["task"] == "gantry_lift" else "peak_limit_fraction"
        assert recorded[measure] == evaluation[measure]  # the re-simulation, bit for bit
    report = (bench / LAYOUT.report).read_text()
    assert "## Closest calls" in report and "closest success 1" in report


def _copy(bench: Path, tmp_path: Path) -> Path:
    workdir = tmp_path / "copy"
    shutil.copytree(bench, workdir, symlinks=True)
    return workdir


def _pooled_by_hand(workdir: Path, task: str, method: str) -> tuple[int, int]:
    """(successes, episodes) of a method on a task over every seed, counted in its tables."""
    success = [
        pq.read_table(workdir / LAYOUT.evaluation(task, method, seed)).column("success").to_pylist()
        for seed in (1, 2, 3)
    ]
    return sum(map(sum, success)), sum(map(len, success))


def test_verify_recomputes_a_forged_summary_and_closest_calls_from_the_tables(bench, tmp_path):
    """A pooled rate and a closest call forged under their stamps, the report, seal and crate
    rebuilt from them: every stamp and the seal agree, the recomputation does not."""
    workdir = _copy(bench, tmp_path)
    summary = workdir / LAYOUT.summary
    data = json.loads(summary.read_text())
    pooled = data["per_task"]["gantry_lift"]["tuned"]["pooled_over_seeds"]
    k, n = _pooled_by_hand(workdir, "gantry_lift", "tuned")
    assert (pooled["successes"], pooled["n"]) == (k, n)
    forged = n if k < n else 0
    pooled.update(successes=forged, rate=forged / n)
    summary.write_text(json.dumps(data, indent=2))
    table_path = workdir / LAYOUT.closest_calls_table
    table = pq.read_table(table_path)
    rows = table.to_pylist()
    rows[0]["state_id"] = (rows[0]["state_id"] + 1) % N_STATES
    provenance.write_parquet(
        pa.Table.from_pylist(rows, schema=table.schema.remove_metadata()),
        table_path,
        provenance.read_stamp(table_path),
    )
    run_snakemake(workdir, "--configfile", CONFIG, "--forcerun", "benchmark_report")
    assert f"({forged}/{n})" in (workdir / LAYOUT.report).read_text()
    done = verify(workdir)
    assert done.returncode == 1, done.stdout + done.stderr
    problems = [line for line in done.stdout.splitlines() if line.startswith("problem")]
    assert len(problems) == 3, done.stdout
    assert problems[0].startswith(
        f"problem  {LAYOUT.summary.as_posix()}: differs from its recomputation: "
        f"per_task.gantry_lift.tuned.pooled_over_seeds.rate: {forged / n} -> {k / n}"
    )
    assert problems[1].startswith(
        f"problem  {LAYOUT.closest_calls_table.as_posix()}: differs from its recomputation: "
        f"row 1: state_id {rows[0]['state_id']} -> "
    )
    assert problems[2].startswith(f"problem  {LAYOUT.report.as_posix()}: differs from its")


def test_verify_names_a_parameter_file_edited_after_training(bench, tmp_path):
    """One tuned parameter changed (its finalists and score still the old ones), and the
    evaluations rerun on it: the training's stamp holds the sha256 of the record it wrote."""
    workdir = _copy(bench, tmp_path)
    rel = LAYOUT.parameters("gantry_lift", "tuned", 1)
    record = json.loads((workdir / rel).read_text())
    name, (low, high) = next(iter(record["tuned"].items()))
    record["parameters"][name] = high if record["parameters"][name] != high else low
    (workdir / rel).write_text(json.dumps(record, indent=2))
    run_snakemake(workdir, "--configfile", CONFIG)
    evaluation = provenance.read_stamp(workdir / LAYOUT.evaluation("gantry_lift", "tuned", 1))
    assert evaluation["inputs"]["parameters"]["sha256"] == provenance.file_sha256(workdir / rel)
    done = verify(workdir)
    assert done.returncode == 1, done.stdout + done.stderr
    problems = [line for line in done.stdout.splitlines() if line.startswith("problem")]
    assert problems == [
        f"problem  {rel.as_posix()}: edited after training (its record's sha256 is not the one "
        "its training stamp holds)",
        f"problem  {rel.as_posix()}: parameters {record['parameters']} are not its best "
        f"finalist's ({max(record['finalists'], key=lambda f: f['score'])['origin']}: "
        f"{max(record['finalists'], key=lambda f: f['score'])['parameters']} with the fixed "
        "values)",
    ]


def test_a_parameter_record_is_consistent_with_its_final_choice(bench):
    from mjtrial.benchmark.config import check_benchmark_config, train_slice
    from mjtrial.benchmark.recompute import record_problems
    from mjtrial.config import read_config_file

    config = read_config_file(bench / CONFIG)
    tasks = check_benchmark_config(config, source=CONFIG, repo_root=bench)
    for task in ("gantry_lift", "cartpole_latency"):
        for method in ("as_designed", "tuned"):
            record = json.loads((bench / LAYOUT.parameters(task, method, 2)).read_text())
            expected = train_slice(config, tasks, task, method, 2)
            assert record_problems(record, expected) == []
            name = next(iter(record["parameters"]))
            forged = {**record, "parameters": {**record["parameters"], name: 0.123}}
            assert len(record_problems(forged, expected)) == 1
    tuned = json.loads((bench / LAYOUT.parameters("cartpole_latency", "tuned", 3)).read_text())
    forged = {**tuned, "score_on_development": tuned["score_on_development"] / 2 + 0.01}
    expected = train_slice(config, tasks, "cartpole_latency", "tuned", 3)
    assert record_problems(forged, expected) == [
        f"score_on_development {forged['score_on_development']} is not its best finalist's "
        f"{tuned['score_on_development']}"
    ]


def test_verify_a_benchmark_from_its_folder_and_resimulate_its_evaluations(bench, tmp_path):
    """Its crate records its config file; `--resimulate K` runs K episodes of every evaluation
    shard again, with the trained parameters, and compares them with the shard's rows."""
    folder = LAYOUT.root.as_posix()
    done = cli(bench, "verify", folder)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"verified: {folder}:" in done.stdout
    # every state of every evaluation: 20 by default, more than any shard holds; 8 states x
    # 3 seeds x (2 methods x 2 tasks, and the MLP's files on the cart-pole)
    assert f"re-simulated {N_STATES * 3 * 5} evaluation episodes" in done.stdout
    workdir = _copy(bench, tmp_path)
    shard = LAYOUT.evaluation_shard("cartpole_latency", "tuned", 2, "00001")
    table = pq.read_table(workdir / shard)
    flipped = table.set_column(
        table.column_names.index("success"),
        "success",
        pa.array([not s for s in table.column("success").to_pylist()]),
    )
    provenance.write_parquet(flipped, workdir / shard, provenance.read_stamp(workdir / shard))
    done = cli(workdir, "verify", folder, "--resimulate", "2")
    assert done.returncode == 1, done.stdout + done.stderr
    # 2 of each shard: 1 shard of the gantry's (6 runs) and 3 of the cart-pole's (9 runs: the
    # MLP's 3 files too)
    assert f"re-simulated {2 * (6 * 1 + 9 * 3)} evaluation episodes (sample seed " in done.stdout
    resimulated = [line for line in done.stdout.splitlines() if "re-simulated episodes" in line]
    assert len(resimulated) == 1, done.stdout
    found = re.fullmatch(
        rf"problem  {re.escape(shard.as_posix())}: differs from its recomputation: re-simulated "
        r"episodes for states (\d+), (\d+) differ in success",
        resimulated[0],
    )
    assert found and all(CARTPOLE_SHARD <= int(i) < 2 * CARTPOLE_SHARD for i in found.groups()), (
        resimulated
    )


def test_verify_of_a_renamed_copy_says_what_it_is(bench):
    copy = LAYOUT.root.with_name("benchmark_cp")
    shutil.copytree(bench / LAYOUT.root, bench / copy, symlinks=True)
    try:
        done = cli(bench, "verify", copy.as_posix())
    finally:
        shutil.rmtree(bench / copy)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        f"mjtrial verify: {copy.as_posix()} is a copy of the run recorded as "
        f"{LAYOUT.root.as_posix()} (its seal lists the outputs there; stamps record paths in "
        f"the repository): verify {LAYOUT.root.as_posix()}, or rebuild this folder with snakemake"
    ]


def test_a_benchmark_diffs_with_its_evaluations_and_comparisons(bench, tmp_path, capsys):
    results = bench / "results" / "benchmark"
    args = [str(results), str(results), "--json", "--fail-on", "any", "--out", str(tmp_path)]
    assert main(["diff", *args]) == 0
    diff = json.loads(capsys.readouterr().out)
    summary = json.loads((results / "analysis" / "summary.json").read_text())
    comparisons = {f"{c['task']}: {c['a']} vs {c['b']}" for c in summary["comparisons"]}
    assert set(diff["effects"]) == comparisons
    evaluations = (results / "evaluation").glob("*/*/seed-*.parquet")
    groups = {p.relative_to(results / "evaluation").with_suffix("").as_posix() for p in evaluations}
    assert set(diff["conditions"]) == groups
    assert diff["made"]["config"] == [] and diff["outputs"]["differ"] == []


def _naive_iqm(scores: list[float]) -> float:
    """The interquartile mean as rliable takes it (scipy's trim_mean at 0.25), by hand: the mean
    of the sorted scores without the lowest and highest quarter (floor(n / 4) each)."""
    x = sorted(scores)
    cut = len(x) // 4
    return float(np.mean(x[cut : len(x) - cut]))


def test_the_mlp_runs_one_file_per_seed_on_the_cartpole_only_and_its_iqm_is_over_them(bench):
    from scipy.stats import trim_mean

    summary = json.loads((bench / LAYOUT.summary).read_text())
    rates = []
    for seed in (1, 2, 3):
        file = MLP.format(seed)
        record = json.loads(
            (bench / LAYOUT.parameters("cartpole_latency", "mlp_es", seed)).read_text()
        )
        assert record["policy"]["path"] == file and record["episodes_used"] == 0
        assert record["policy"]["sha256"] == provenance.file_sha256(bench / file)
        assert record["parameters"] == {"latency": 0.02}  # the benchmark's condition
        train = provenance.read_stamp(bench / LAYOUT.parameters("cartpole_latency", "mlp_es", seed))
        shards = (bench / LAYOUT.evaluation("cartpole_latency", "mlp_es", seed)).with_suffix("")
        stamps = [train] + [provenance.read_stamp(p) for p in sorted(shards.glob("*.parquet"))]
        for stamp in stamps:  # graph and contract, with their sha256, in every stamp
            assert [r["path"] for r in stamp["inputs"]["policy"]] == [
                file,
                "policies/cartpole_mlp/policy.yaml",
            ]
            assert stamp["inputs"]["policy"][0]["sha256"] == record["policy"]["sha256"]
        assert stamps[1]["config_slice"]["policy"] == file
        assert "policy_runtime" in stamps[1]["extra"]
        success = pq.read_table(bench / LAYOUT.evaluation("cartpole_latency", "mlp_es", seed))
        rates.append(float(np.mean(success.column("success").to_numpy())))
    mlp = summary["overall"]["mlp_es"]
    assert mlp["tasks"] == ["cartpole_latency"] and summary["not_run"] == {
        "mlp_es": ["gantry_lift"]
    }
    assert "mlp_es" not in summary["per_task"]["gantry_lift"]
    assert mlp["iqm"]["estimate"] == pytest.approx(trim_mean(rates, 0.25))
    assert mlp["iqm"]["estimate"] == pytest.approx(_naive_iqm(rates))
    assert [mlp["task_mean"]["per_seed"][str(s)]["estimate"] for s in (1, 2, 3)] == (
        pytest.approx(rates)
    )
    spread = summary["per_task"]["cartpole_latency"]["mlp_es"]["spread_over_seeds"]
    assert (spread["min"], spread["max"]) == (pytest.approx(min(rates)), pytest.approx(max(rates)))
    assert {
        (c["a"], c["b"], c["task"]) for c in summary["comparisons"] if "mlp_es" in (c["a"], c["b"])
    } == {
        ("as_designed", "mlp_es", "cartpole_latency"),
        ("tuned", "mlp_es", "cartpole_latency"),
    }
    # the tuned methods' numbers are over both tasks, as without the MLP
    assert "tasks" not in summary["overall"]["tuned"]
    report = (bench / LAYOUT.report).read_text()
    assert "| gantry_lift | mlp_es | not run on this task | |" in report
    assert "- mlp_es (cartpole_latency only): " in report
    for seed in (1, 2, 3):
        sha = provenance.file_sha256(bench / MLP.format(seed))[:12]
        assert f"| cartpole_latency | mlp_es | {seed} | {MLP.format(seed)} | {sha} |" in report
    # the crate lists each file the run read (and its copy of the sources holds it)
    entities = {e["@id"]: e for e in json.loads((bench / LAYOUT.crate).read_text())["@graph"]}
    for file in [MLP.format(s) for s in (1, 2, 3)] + ["policies/cartpole_mlp/policy.yaml"]:
        assert entities[f"source/{file}"]["sha256"] == provenance.file_sha256(bench / file)


def test_a_policy_file_edited_after_the_run_reruns_its_seed_and_fails_verify(bench, tmp_path):
    """One byte of the second seed's graph changed (a weight): the plan reruns that seed's
    training and evaluation and what reads every seed, nothing else; verify names the file."""
    workdir = _copy(bench, tmp_path)
    file = workdir / MLP.format(2)
    data = bytearray(file.read_bytes())
    at = data.index(b"w1J") + 3  # the initializer w1's raw data (field 9): its length, then floats
    while data[at] & 0x80:
        at += 1
    data[at + 1] ^= 0x01  # the low bit of its first weight: a valid graph, another network
    file.write_bytes(bytes(data))
    assert planned(workdir) == {
        "train": 1,
        "evaluate": 3,
        "evaluate_gather": 1,
        "benchmark_summary": 1,
        "closest_calls": 1,
        "benchmark_report": 1,
        "benchmark_seal": 1,
        "benchmark_crate": 1,
        "all": 1,
    }
    done = verify(workdir)
    assert done.returncode == 1, done.stdout + done.stderr
    problems = [line for line in done.stdout.splitlines() if line.startswith("problem")]
    assert problems[0].startswith(
        f"problem  {MLP.format(2)}: policy file changed since the run "
        f"({LAYOUT.parameters('cartpole_latency', 'mlp_es', 2).as_posix()} read it with sha256 "
    ), done.stdout
    # an evaluation of the old record with the edited file is refused before any episode
    from mjtrial.stages.evaluate import evaluate_method

    parameters = workdir / LAYOUT.parameters("cartpole_latency", "mlp_es", 2)
    with pytest.raises(ValueError) as err:
        evaluate_method(
            states=workdir / LAYOUT.task("cartpole_latency").states,
            parameters=parameters,
            model_file=workdir / "tasks" / "cartpole_latency" / "cartpole.xml",
            evaluate_slice={"task": "tasks/cartpole_latency/task.py"},
            output=tmp_path / "never.parquet",
            repo_root=workdir,
        )
    assert str(err.value).startswith(
        f"{parameters}: {MLP.format(2)} is not the file its training recorded (sha256 differs)"
    )
    assert not (tmp_path / "never.parquet").exists()
