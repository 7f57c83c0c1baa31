"""`mjtrial replay` for any task: the cart-pole (closed loop) on the committed model and on a
simulator variant, its experiment found from its results folder. And what a task prints goes to
its job's log, in a rollout's process and in a job run inside Snakemake's."""

from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT, WORKFLOW_FILES, run_snakemake

from mjtrial.cli import main
from mjtrial.replay import replay_episode

pytestmark = pytest.mark.end_to_end

CONFIG = "config/cartpole_small.yaml"
RESULTS = "results/cartpole_small"
PRINTED = "the cart-pole task judges its episodes"


@pytest.fixture(scope="module")
def cartpole_run(tmp_path_factory) -> Path:
    """The cart-pole experiment at 16 states with no recordings, and one variant's rollouts;
    its task prints a line each time it judges episodes. What Snakemake printed is kept in
    `console.txt` (the run) and `dry_console.txt` (a dry run: the preflight's prints only)."""
    workdir = tmp_path_factory.mktemp("cartpole")
    for name in WORKFLOW_FILES:
        src = REPO_ROOT / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, workdir / name)
    task = workdir / "tasks" / "cartpole_latency" / "task.py"
    judge = "def success(episodes: Episodes) -> np.ndarray:\n"
    task.write_text(task.read_text().replace(judge, f"{judge}    print({PRINTED!r})\n"))
    config = yaml.safe_load((REPO_ROOT / "config" / "cartpole_latency.yaml").read_text())
    config["experiment"] = "cartpole_small"
    config["states"]["n"] = 16
    config["rollout"]["shard_size"] = 16
    config["recording"]["episodes"] = "none"
    config["analysis"]["n_resamples"] = 200
    config["variants"] = {"rk4": config["variants"]["rk4"]}
    (workdir / CONFIG).write_text(yaml.safe_dump(config, sort_keys=False))
    targets = [f"{RESULTS}/manifest.json", f"{RESULTS}/variants/rk4/rollouts/latency_20ms.parquet"]
    for name, dry in (("dry_console.txt", ["-n"]), ("console.txt", [])):
        proc = run_snakemake(workdir, *dry, *targets, "--configfile", CONFIG)
        (workdir / name).write_text(proc.stdout + proc.stderr)
    return workdir


def _row(path: Path, state_id: int) -> dict:
    [row] = [r for r in pq.read_table(path).to_pylist() if r["state_id"] == state_id]
    return row


@pytest.mark.parametrize(
    ("variant", "table"),
    [
        ("nominal", "rollouts/latency_20ms.parquet"),
        ("rk4", "variants/rk4/rollouts/latency_20ms.parquet"),
    ],
)
def test_replay_prints_the_tasks_own_outcome(cartpole_run, monkeypatch, capsys, variant, table):
    monkeypatch.chdir(cartpole_run)
    rows = pq.read_table(cartpole_run / RESULTS / table).to_pylist()
    # A failure and a success where both exist: each is worded from its own row.
    picks = {r["success"]: r for r in rows}
    for row in picks.values():
        state = row["state_id"]
        code = main(
            ["replay", RESULTS, "--condition", "latency_20ms", "--state", str(state)]
            + ["--variant", variant, "--no-viewer"]
        )
        out = capsys.readouterr()
        assert code == 0, out.err
        expected = "success" if row["success"] else f"failure ({row['failure_category']})"
        assert f"state {state}: {expected}, " in out.out
        assert f"peak_angle {row['peak_angle']:.4g} rad" in out.out
        assert f"final_angle {row['final_angle']:.4g} rad" in out.out
        assert "final_height" not in out.out


def test_replayed_variant_episode_is_its_row(cartpole_run, tmp_path):
    replay = replay_episode(
        condition="latency_20ms",
        state_id=5,
        variant="rk4",
        output=tmp_path / "rk4.rrd",
        config_path=cartpole_run / CONFIG,
        results_dir=cartpole_run / RESULTS,
        repo_root=cartpole_run,
    )
    row = _row(cartpole_run / RESULTS / "variants/rk4/rollouts/latency_20ms.parquet", 5)
    assert replay.condition == "rk4/latency_20ms"
    assert {k: replay.outcome[k] for k in row} == row
    # The variant's episode is not the committed model's: the replay ran the variant.
    assert replay.outcome != _row(cartpole_run / RESULTS / "rollouts/latency_20ms.parquet", 5)


def test_replay_says_when_a_config_is_needed(cartpole_run, monkeypatch, capsys):
    monkeypatch.chdir(cartpole_run)
    # No results folder and no --config: config/config.yaml, the gantry's experiment.
    code = main(["replay", "--condition", "latency_20ms", "--state", "0", "--no-viewer"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and len(err.splitlines()) == 1
    assert "condition 'latency_20ms'" in err and "--config" in err
    code = main(
        ["replay", RESULTS, "--condition", "latency_20ms", "--state", "0", "--variant", "euler"]
    )
    err = capsys.readouterr().err.strip()
    assert code == 1 and "variant 'euler': expected one of ['nominal', 'rk4']" in err
    # A results folder with no manifest: say that --config is needed.
    bare = cartpole_run / "results" / "bare"
    bare.mkdir()
    code = main(["replay", str(bare), "--condition", "latency_20ms", "--state", "0"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--config" in err


def test_what_a_task_prints_is_in_its_jobs_log(cartpole_run):
    logs = cartpole_run / RESULTS / "logs"
    # A rollout (a process of its own) and a gather (a thread of Snakemake's process, which
    # judges the nominal episode) print into their own logs.
    for job in (
        "rollout_latency_20ms_00000",
        "gather_no_latency",
        "rollout_rk4_latency_20ms_00000",
    ):
        assert PRINTED in (logs / f"{job}.log").read_text(), job
    # On the console only what Snakemake printed before any job: the config check's episodes.
    # The dry run checked the config (its episodes printed); the run after it, with nothing
    # changed, skipped the check (its pass remembered: mjtrial.config.passes), so nothing the
    # task printed reaches its console: its jobs printed into their logs.
    assert (cartpole_run / "dry_console.txt").read_text().count(PRINTED) > 0
    assert (cartpole_run / "console.txt").read_text().count(PRINTED) == 0


def test_replay_during_a_run_says_what_is_missing_before_any_work(tmp_path, monkeypatch, capsys):
    """A run still going: states drawn, one of the condition's three shards written, no
    gathered table. The replay says so in words, before checking the config (which runs
    episodes of its own) or simulating anything."""
    from conftest import copy_workflow, edit_config

    import mjtrial.replay as replay

    workdir = copy_workflow(tmp_path)
    edit_config(workdir, lambda c: (c["states"].update(n=12), c["rollout"].update(shard_size=5)))
    results = workdir / "results" / "research_mode"
    never = lambda *a, **k: pytest.fail("worked before checking its inputs")  # noqa: E731
    monkeypatch.setattr(replay, "check_config", never)
    monkeypatch.setattr(replay, "condition_batches", never)
    with pytest.raises(replay.NotYetWritten) as err:
        replay.replay_episode(condition="fast", state_id=3, repo_root=workdir)
    assert str(err.value) == (
        f"{results / 'states.parquet'}: not written; the run has not drawn its initial states "
        "yet (run `snakemake -c2`, or wait for the run going on)"
    )
    (results / "rollouts" / "fast").mkdir(parents=True)
    (results / "states.parquet").touch()
    (results / "rollouts" / "fast" / "shard-00000.parquet").touch()
    with pytest.raises(replay.NotYetWritten) as err:
        replay.replay_episode(condition="fast", state_id=3, repo_root=workdir)
    assert str(err.value) == (
        f"{results / 'rollouts' / 'fast.parquet'}: not written yet; a condition's episodes are "
        "gathered into it once all its shards have run, and 1 of its 3 shards have run. Replay "
        "reads that table: wait for the run to finish (or finish it with `snakemake -c2`), "
        "then replay"
    )
    # the command: one line in words, the manifest's absence said too
    monkeypatch.chdir(workdir)
    args = ["replay", str(results), "--condition", "fast", "--state", "3", "--no-viewer"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"mjtrial replay: {results / 'manifest.json'}: not written yet (a run writes it last: "
        "it is going on, or stopped); give the experiment's --config"
    )
    assert main([*args, "--config", "config/config.yaml"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "1 of its 3 shards have run" in err
