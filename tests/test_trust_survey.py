"""The second hostile survey: each case a way the pipeline or `mjtrial verify` was fooled, or
results were lost; each test failed before its fix."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import edit_config, run_snakemake
from test_nothing_lost import digest

pytestmark = pytest.mark.end_to_end

RESULTS = Path("results") / "research_mode"


def copy_of(built: Path, tmp_path: Path) -> Path:
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir)
    return workdir


def test_mostly_unhealthy_episodes_make_the_main_verdict_invalid(built, tmp_path):
    """Survey case 9: masses up to 1e30 make most episodes "simulation unhealthy"; the main
    falsifier must say invalid, not refuted, and the report must say so."""
    workdir = copy_of(built, tmp_path)

    def heavy(config):
        config["rollout"]["shard_size"] = 12  # every rollout runs again: a job per condition
        config["states"]["ranges"]["mass"] = [0.05, 1e30]
        config["analysis"]["bands"]["mass"] = [0.05, 1.0, 1e30]

    edit_config(workdir, heavy)
    run_snakemake(workdir)
    summary = json.loads((workdir / RESULTS / "analysis" / "summary.json").read_text())
    unhealthy = sum(summary["conditions"][c]["unhealthy"] for c in ("fast", "slow"))
    assert unhealthy > 0
    assert summary["falsifier"]["verdict"] == "invalid"
    assert f"{unhealthy} of 24 episodes unhealthy" in summary["falsifier"]["reason"]
    assert "Verdict: **INVALID**" in (workdir / RESULTS / "report.md").read_text()


def test_an_edit_to_an_include_in_another_folder_reruns_and_is_stale(built, tmp_path):
    """Survey case 1: the robot's XML moved to models/common/ and included from the scene; an
    edit to its force range there is planned for a rerun and verify calls the rollouts stale."""
    from mjtrial.verify import Status, verify_results

    workdir = copy_of(built, tmp_path)
    models = workdir / "models"
    (models / "common").mkdir()
    (models / "gantry_gripper" / "gantry_gripper.xml").rename(models / "common" / "robot.xml")
    scene = models / "gantry_gripper" / "scene.xml"
    scene.write_text(
        scene.read_text().replace('file="gantry_gripper.xml"', 'file="../common/robot.xml"')
    )
    # every rollout runs again (the model's files moved): a job per condition
    edit_config(workdir, lambda c: c["rollout"].update(shard_size=12))
    run_snakemake(workdir)
    assert "Nothing to be done" in run_snakemake(workdir, "-n").stdout
    robot = models / "common" / "robot.xml"
    robot.write_text(robot.read_text().replace('forcerange="-18 18"', 'forcerange="-12 12"'))
    plan = run_snakemake(workdir, "-n").stdout
    assert "rollout" in plan and "Nothing to be done" not in plan
    report = verify_results(
        workdir / RESULTS, config_path=workdir / "config" / "config.yaml", repo_root=workdir
    )
    shard = (RESULTS / "rollouts" / "fast" / "shard-00000.parquet").as_posix()
    assert report[shard].status is Status.STALE, report.format()
    assert "models/common/robot.xml" in " ".join(report[shard].reasons)


def verified(workdir: Path):
    from mjtrial.verify import verify_results

    return verify_results(
        workdir / RESULTS, config_path=workdir / "config" / "config.yaml", repo_root=workdir
    )


@pytest.fixture
def other_filesystem():
    """A folder on another filesystem than the tests' temporary folders (a tmpfs)."""
    import os
    import tempfile

    shm = Path("/dev/shm")
    if not shm.is_dir() or os.stat(shm).st_dev == os.stat(tempfile.gettempdir()).st_dev:
        pytest.skip("no tmpfs beside the temporary folder")
    folder = Path(tempfile.mkdtemp(dir=shm, prefix="mjtrial-test-"))
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def test_results_on_another_filesystem_lose_nothing_and_verify(built, tmp_path, other_filesystem):
    """Survey case 5: `results` a symlink to a tmpfs; a failing job puts everything back, the
    next run is not wedged, and verify accepts the symlinked folder."""
    workdir = copy_of(built, tmp_path)
    shutil.move(workdir / "results", other_filesystem / "results")
    (workdir / "results").symlink_to(other_filesystem / "results")
    states = workdir / RESULTS / "states.parquet"
    good_states = states.read_bytes()
    states.write_bytes(b"not a parquet file")  # the rollouts, forced, fail at run time
    before = digest(workdir / RESULTS)
    proc = run_snakemake(workdir, "--forcerun", "rollout", check=False)
    assert proc.returncode != 0
    assert "Invalid cross-device link" not in proc.stderr
    assert "the previous results were put back unchanged" in proc.stderr, proc.stderr
    assert digest(workdir / RESULTS) == before
    states.write_bytes(good_states)
    run_snakemake(workdir)  # not wedged
    assert verified(workdir).ok, verified(workdir).format()


def start_and_kill(workdir: Path, *args: str, when: Path) -> None:
    """Start `snakemake -c2 *args`, SIGKILL its whole process group once the job log `when`
    has been written anew (the job has started: its outputs are removed)."""
    import os
    import signal
    import subprocess
    import time

    from conftest import SNAKEMAKE

    when.unlink(missing_ok=True)
    proc = subprocess.Popen(
        [SNAKEMAKE, "-c2", *args],
        cwd=workdir,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.monotonic() + 120
    while not when.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.02)
    assert proc.poll() is None, "the run finished before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def test_the_documented_recovery_after_a_kill_restores_everything(built, tmp_path):
    """Survey case 6: edit lift_time, run, kill -9 during the rollouts, revert the config,
    `snakemake --unlock && snakemake -c2 --rerun-incomplete`: every output back with the data
    it had (shards the killed run had finished with the edited value are rebuilt; Snakemake
    runs them in no fixed order), nothing left behind, verify ok. Before the fix the killed
    job's outputs stayed missing and Snakemake had nothing to do."""
    from test_trust import _data

    workdir = copy_of(built, tmp_path)
    before = _data(workdir / RESULTS)
    config = workdir / "config" / "config.yaml"
    original = config.read_text()
    edit_config(workdir, lambda c: c["conditions"]["fast"].update(lift_time=0.2))
    start_and_kill(workdir, when=workdir / RESULTS / "logs" / "rollout_fast_00000.log")
    config.write_text(original)
    run_snakemake(workdir, "--unlock")
    run_snakemake(workdir, "--rerun-incomplete")
    after = _data(workdir / RESULTS)
    # the killed run's edited design is on the record as a deviation from the registration
    assert "conditions.fast.lift_time" in json.dumps(after.pop("deviations.json"))
    assert after.keys() == before.keys()
    for name, value in before.items():
        assert value.equals(after[name]) if hasattr(value, "equals") else value == after[name]
    assert not list((workdir / RESULTS).rglob(".*.tmp-*"))
    assert not (workdir / RESULTS / ".snapshot").exists()
    assert verified(workdir).ok, verified(workdir).format()


def test_a_deleted_results_folder_does_not_come_back(built, tmp_path):
    """Survey case 7: kill a run, delete its results folder, switch to another experiment and
    run: the deleted folder stays deleted."""
    workdir = copy_of(built, tmp_path)
    start_and_kill(
        workdir,
        "--forcerun",
        "rollout",
        when=workdir / RESULTS / "logs" / "rollout_fast_00000.log",
    )
    shutil.rmtree(workdir / RESULTS)

    def fresh(config):  # another experiment, small: one shard of 5 states per condition
        config.update(experiment="fresh")
        config["states"]["n"] = 5
        config["analysis"]["first_k"] = 5

    edit_config(workdir, fresh)
    run_snakemake(workdir, "--unlock")
    proc = run_snakemake(workdir)
    assert "put back" not in proc.stderr
    assert not (workdir / RESULTS).exists()
    assert (workdir / "results" / "fresh" / "seal.json").is_file()


# Every documented condition parameter besides lift_time, at a value other than its default.
CONDITION_PARAMETERS = [
    ("settle_time", 0.4),
    ("pre_close_time", 0.2),
    ("close_time", 0.8),
    ("hold_time", 1.0),
    ("gripper_closed", 0.002),
]


def test_every_condition_parameter_works_end_to_end(built, tmp_path):
    """Survey case 10: a condition that sets the parameter builds the report, and replay
    reproduces its episodes (a hold of 1.0 s once failed the report: "2350 steps recorded").
    One run, a condition per parameter (the slow lift with that one value changed)."""
    import pyarrow.parquet as pq

    from mjtrial.recording import read_episode
    from mjtrial.replay import replay_episode

    workdir = copy_of(built, tmp_path)

    def add_conditions(c):
        # 3 states (every rollout runs again anyway: a job per condition, not three)
        c["states"]["n"] = c["analysis"]["first_k"] = 3
        c["rollout"]["shard_size"] = 3
        slow = c["conditions"]["slow"]
        for parameter, value in CONDITION_PARAMETERS:
            c["conditions"][f"with_{parameter}"] = {**slow, parameter: value}

    edit_config(workdir, add_conditions)
    run_snakemake(workdir)
    for parameter, _ in CONDITION_PARAMETERS:
        name = f"with_{parameter}"
        table = pq.read_table(workdir / RESULTS / "rollouts" / f"{name}.parquet").to_pylist()
        row = table[0]
        out = tmp_path / f"{name}.rrd"
        replay = replay_episode(condition=name, state_id=0, output=out, repo_root=workdir)
        assert replay.outcome["final_height"] == row["final_height"], parameter
        episode = read_episode(out, condition=name, state_id=0)
        assert episode["cube_height"][-1] == row["final_height"], parameter
    assert verified(workdir).ok, verified(workdir).format()


def test_a_sweep_over_a_hold_is_planned(built, tmp_path):
    """Survey case 10: a sweep over hold_time gave a PointerToNowhere stack dump on every call."""
    workdir = copy_of(built, tmp_path)
    edit_config(workdir, lambda c: c["sweep"].update(parameter="hold_time", values=[0.3, 0.5, 0.8]))
    proc = run_snakemake(workdir, "-n", "dose_response")
    assert "PointerToNowhere" not in proc.stderr
    assert "rollout" in proc.stdout


def test_design_text_cannot_end_a_script_of_the_html_report(built, tmp_path):
    """Survey 2 (minor): the rules' params (config slices with the design's text) were written
    raw into a <script> element of `snakemake --report`'s page."""
    workdir = copy_of(built, tmp_path)
    injected = "</script><script>window.injected = 1</script>"
    edit_config(workdir, lambda c: c["design"].update(question=f"Does it {injected} hold?"))
    run_snakemake(workdir)
    run_snakemake(workdir, "--report", "report.html")
    page = (workdir / "report.html").read_text()
    assert "window.injected" in page  # the question is in the page...
    assert injected not in page  # ...but cannot close the script it sits in


@pytest.mark.parametrize(
    "edit",
    [
        lambda c: c["states"].update(n=8),  # shard-00002 of the 12 states is left over
        lambda c: c["rollout"].update(shard_size=4),  # three shards of another range
    ],
    ids=["fewer states", "another shard size"],
)
def test_leftovers_of_an_earlier_configuration_raise_no_false_alarm(built, tmp_path, edit):
    """Survey case 4: outputs an earlier configuration left in the folder are not the current
    run's inputs: the stamps do not list them, and verify passes."""
    workdir = copy_of(built, tmp_path)
    edit_config(workdir, lambda c: (edit(c), c["analysis"].update(first_k=8)))
    run_snakemake(workdir)
    assert "Nothing to be done" in run_snakemake(workdir, "-n").stdout
    report = verified(workdir)
    assert report.ok, report.format()


def test_a_checkout_run_with_another_checkouts_package_is_refused(tmp_path):
    """Survey case 3: a checkout whose own src/mjtrial is not the imported package (another
    checkout's editable install) is refused in one line naming both, by the pipeline and by
    verify; with its own package on the path it runs."""
    import subprocess
    import sys

    from conftest import REPO_ROOT, WORKFLOW_FILES

    checkout = tmp_path / "other"
    checkout.mkdir()
    for name in (*WORKFLOW_FILES, "src"):
        src = REPO_ROOT / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, checkout / name)
    own = (checkout / "src" / "mjtrial").resolve()
    proc = run_snakemake(checkout, "-n", check=False)
    lines = [x for x in proc.stderr.splitlines() if x.strip() and not x.startswith("Using ")]
    assert proc.returncode != 0 and len(lines) == 1, proc.stderr
    assert str(own) in lines[0] and str(REPO_ROOT / "src" / "mjtrial") in lines[0]
    verify = subprocess.run(
        [sys.executable, "-m", "mjtrial.cli", "verify"],
        cwd=checkout,
        capture_output=True,
        text=True,
    )
    assert verify.returncode == 2 and str(own) in verify.stderr
    ran = run_snakemake(checkout, "-n", env={"PYTHONPATH": str(checkout / "src")})
    assert "states" in ran.stdout


def test_leftovers_of_a_removed_variant_and_sweep_value_raise_no_false_alarm(built, tmp_path):
    """Survey case 4: a variant and a sweep value removed after the studies ran leave their
    rollouts behind; verify names them skipped and passes."""
    workdir = copy_of(built, tmp_path)

    def studies(variants, values):
        def edit(config):
            config["variants"] = {v: {"option": {"timestep": dt}} for v, dt in variants.items()}
            config["sweep"]["values"] = values

        return edit

    # one shard of the 12 states: a job per condition and variant, not three
    edit_config(workdir, lambda c: c["rollout"].update(shard_size=12))
    edit_config(workdir, studies({"step_1ms": 0.001, "step_4ms": 0.004}, [0.15, 0.3, 0.6, 1.5]))
    run_snakemake(workdir, "studies")
    edit_config(workdir, studies({"step_1ms": 0.001}, [0.15, 0.6, 1.5]))
    run_snakemake(workdir, "studies")
    assert "Nothing to be done" in run_snakemake(workdir, "-n", "studies").stdout
    report = verified(workdir)
    assert report.ok, report.format()
    skipped = " ".join(s.path for s in report.skipped)
    assert "variants/step_4ms/rollouts/" in skipped and "0.3" in skipped, skipped


def test_a_run_given_command_line_values_verifies_against_them(built, tmp_path):
    """Survey case 4: a run with --config is checked against the configuration it used (the
    manifest records the values), and verify says how it differs from the file."""
    workdir = copy_of(built, tmp_path)
    run_snakemake(workdir, "--config", "analysis={n_resamples: 300}")
    manifest = json.loads((workdir / RESULTS / "manifest.json").read_text())
    command = "snakemake -c2 --config 'analysis={n_resamples: 300}'"
    assert manifest["rerun"]["command"] == command
    assert manifest["rerun"]["command_line"] == {"analysis": {"n_resamples": 300}}
    assert (
        "Nothing to be done"
        in run_snakemake(workdir, "-n", "--config", "analysis={n_resamples: 300}").stdout
    )

    report = verified(workdir)
    assert report.ok, report.format()
    [warning] = [w for w in report.warnings if "command line" in w]
    assert command in warning and "analysis.n_resamples: 500 -> 300" in warning

    run_snakemake(workdir)  # the file's configuration again: no warning
    report = verified(workdir)
    assert report.ok and not report.warnings, report.format()
