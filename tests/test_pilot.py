"""The pilot (`snakemake -c2 pilot`): every condition on the development states, under
`development/`, with its rates; never read by the evaluation (no rule `snakemake -c2` plans
lists a development output as input, and the analysis refuses one), stamped and verified, and
a stale pilot (one of an earlier configuration) does not fail `mjtrial verify`."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, edit_config, run_snakemake
from gantry_lift.model_spec import ModelSpec
from gantry_lift.protocol import PROTOCOL
from gantry_lift.simulate import reference_episode
from gantry_lift.states import states_from_table
from scipy.stats import binomtest

from mjtrial import provenance
from mjtrial.files.layout import Layout
from mjtrial.sim.physics import load_model
from mjtrial.stages.analysis import run_analysis
from mjtrial.stages.stamping import config_slice
from mjtrial.stages.states import build_states
from mjtrial.verify import Status, verify_results

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")
DEVELOPMENT = LAYOUT.development
# The pilot is run with the fast lift at 0.2 s; the config's is 0.15 s: a pilot of an earlier
# configuration, as after tuning on it.
PILOT_CONFIG = "conditions={fast: {lift_time: 0.2}, slow: {lift_time: 1.5}}"


def planned_jobs(workdir: Path, *args: str) -> dict[str, list[tuple[list[str], list[str]]]]:
    """Rule -> (outputs, inputs) of every job Snakemake plans for `args`, as a dry run of
    every job (`-n --forceall`) prints them: Snakemake's own record of each job's files."""
    out = run_snakemake(workdir, "-n", "--forceall", *args).stdout
    jobs: dict[str, list[tuple[list[str], list[str]]]] = {}
    for block in re.split(r"^(?:local)?rule ", out, flags=re.MULTILINE)[1:]:
        rule = block.split(":", 1)[0]
        files = {
            m[1]: m[2].split(", ") for m in re.finditer(r"^    (input|output): (.*)$", block, re.M)
        }
        jobs.setdefault(rule, []).append((files.get("output", []), files.get("input", [])))
    return jobs


@pytest.fixture(scope="module")
def workflow(tmp_path_factory) -> Path:
    """The workflow's files, 12 states in shards of 5, nothing built."""
    workdir = copy_workflow(tmp_path_factory.mktemp("pilot_plan"))
    edit_config(workdir, lambda c: (c["states"].update(n=12), c["rollout"].update(shard_size=5)))
    return workdir


@pytest.fixture(scope="module")
def workflow_plan(workflow):
    """`planned_jobs` of the unbuilt `workflow`, each set of arguments dry-run once (a dry run
    changes nothing there, so another one of the same arguments plans the same jobs)."""
    plans: dict[tuple[str, ...], dict] = {}

    def plan(*args: str):
        if args not in plans:
            plans[args] = planned_jobs(workflow, *args)
        return plans[args]

    return plan


@pytest.mark.parametrize("target", [[], ["studies"]])
def test_no_rule_of_the_evaluation_reads_a_development_output(workflow_plan, target):
    jobs = workflow_plan(*target)
    assert {"analysis", "manifest", "report"} <= set(jobs) or target
    development = f"{DEVELOPMENT.root.as_posix()}/"
    read = [
        f"{rule} reads {source}"
        for rule, rows in jobs.items()
        for outputs, inputs in rows
        for source in inputs
        if source.startswith(development)
        and not all(o.startswith(development) for o in outputs)  # a development job's own
    ]
    assert read == []
    # the check sees what a job reads: the analysis reads the evaluation's tables
    assert any("rollouts/fast.parquet" in s for _, i in jobs.get("analysis", []) for s in i)
    assert not {"pilot", "development_states", "pilot_rollout", "pilot_gather"} & set(jobs)


def test_the_pilot_writes_under_development_only_and_reads_development_states(workflow_plan):
    jobs = workflow_plan("pilot")
    assert set(jobs) == {
        *("development_states", "pilot_rollout", "pilot_gather", "pilot_summary", "pilot")
    }
    development = f"{DEVELOPMENT.root.as_posix()}/"
    outputs = [o for rows in jobs.values() for out, _ in rows for o in out]
    assert outputs and all(o.startswith(development) for o in outputs)
    states = {s for _, inputs in jobs["pilot_rollout"] for s in inputs if s.endswith(".parquet")}
    assert states == {DEVELOPMENT.states.as_posix()}
    assert len(jobs["pilot_rollout"]) == 2 * 3  # two conditions, shards of 5 of 12 states


def test_pilot_n_runs_the_first_development_states_only(workflow_plan):
    # 7 of the 12 development states, in shards of 5: 2 per condition
    jobs = workflow_plan("pilot", "--config", "pilot={n: 7}")
    assert len(jobs["pilot_rollout"]) == 2 * 2
    gathered = [i for _, inputs in jobs["pilot_gather"] for i in inputs if "shard-" in i]
    assert sorted({Path(i).name for i in gathered}) == [
        "shard-00000.parquet",
        "shard-00001.parquet",
    ]
    # the development states are drawn as before: states.n of them, one job
    assert len(jobs["development_states"]) == 1
    # the evaluation is untouched
    evaluation = workflow_plan("--config", "pilot={n: 7}")
    assert len(evaluation["rollout"]) == len(workflow_plan()["rollout"])


def test_a_pilot_of_3_states_runs_and_verifies(workflow, tmp_path):
    """A real pilot of the first 3 of the 12 development states: its tables, rates and
    `mjtrial verify` (which re-simulates its sample from the same 3 states)."""
    workdir = tmp_path / "experiment"
    shutil.copytree(workflow, workdir, symlinks=True)
    edit_config(workdir, lambda c: c.update(pilot={"n": 3}))
    run_snakemake(workdir, "pilot")
    development = pq.read_table(workdir / DEVELOPMENT.states)
    assert development.num_rows == 12  # drawn as before
    summary = json.loads(provenance.read_output_text(workdir / LAYOUT.pilot_summary))
    for condition in ("fast", "slow"):
        table = pq.read_table(workdir / DEVELOPMENT.rollout_table(condition))
        assert table.column("state_id").to_pylist() == [0, 1, 2]
        assert summary["conditions"][condition]["n"] == 3
    report = verify_results(
        workdir / LAYOUT.root, config_path=workdir / "config" / "config.yaml", repo_root=workdir
    )
    checked = [
        DEVELOPMENT.shard_table("fast", "00000"),
        *(DEVELOPMENT.rollout_table(c) for c in ("fast", "slow")),
        LAYOUT.pilot_summary,
    ]
    for path in checked:
        assert report.status_of(path.as_posix()) is Status.OK, report.format()
    assert not any(w.startswith("development output") for w in report.warnings), report.format()


def test_pilot_n_above_the_development_states_is_one_line_naming_the_key(workflow):
    proc = run_snakemake(workflow, "-n", "pilot", "--config", "pilot={n: 13}", check=False)
    assert proc.returncode != 0
    assert "pilot.n" in proc.stderr and "expected at most states.n (12" in proc.stderr


@pytest.fixture(scope="module")
def piloted(built, tmp_path_factory) -> Path:
    """The built experiment (12 states, shards of 5) and a pilot run with the fast lift at 0.2 s."""
    workdir = tmp_path_factory.mktemp("piloted") / "experiment"
    shutil.copytree(built, workdir, symlinks=True)
    run_snakemake(workdir, "pilot", "--config", PILOT_CONFIG)
    return workdir


def test_the_pilot_runs_every_condition_on_the_development_states(piloted):
    model = load_model(REPO_ROOT / "models" / "gantry_gripper" / "scene.xml")
    z = ModelSpec.of(model).state_cube_z
    states = states_from_table(pq.read_table(piloted / DEVELOPMENT.states))
    summary = json.loads(provenance.read_output_text(piloted / LAYOUT.pilot_summary))
    assert "pilot" in summary["pilot"] and summary["states"] == "development"
    for condition, lift_time in (("fast", 0.2), ("slow", 1.5)):
        table = pq.read_table(piloted / DEVELOPMENT.rollout_table(condition))
        # each development state's outcome as the gantry's literal mj_step loop gives it
        heights = [reference_episode(model, s, lift_time=lift_time)[0][-1, z] for s in states]
        expected = [bool(h > PROTOCOL.success_height) for h in heights]
        assert table.column("state_id").to_pylist() == [s.state_id for s in states]
        assert table.column("success").to_pylist() == expected
        record = summary["conditions"][condition]
        assert (record["lift_time"], record["n"], record["successes"]) == (
            lift_time,
            len(states),
            sum(expected),
        )
        interval = binomtest(sum(expected), len(states)).proportion_ci(0.95, method="wilson")
        assert record["wilson_low"] == pytest.approx(interval.low, abs=1e-12)
        assert record["wilson_high"] == pytest.approx(interval.high, abs=1e-12)
        stamp = provenance.read_stamp(piloted / DEVELOPMENT.shard_table(condition, "00000"))
        assert stamp["rule"] == f"pilot:{condition}#00000"
        assert stamp["inputs"]["states"]["path"].endswith("development/states.parquet")


def test_changing_a_condition_reruns_its_pilot_shards_and_the_rates_only(piloted):
    # the pilot ran fast at 0.2 s; the config says 0.15 s: fast's 3 shards, slow's none
    out = run_snakemake(piloted, "-n", "pilot").stdout
    table = out.split("Job stats:")[1].split("total")[0]
    jobs = dict(line.split() for line in table.splitlines()[3:] if line.strip())
    assert jobs == {"pilot_rollout": "3", "pilot_gather": "1", "pilot_summary": "1", "pilot": "1"}


def verify(workdir: Path):
    return verify_results(
        workdir / LAYOUT.root, config_path=workdir / "config" / "config.yaml", repo_root=workdir
    )


def test_a_stale_pilot_is_a_note_and_a_current_one_is_checked(piloted, tmp_path):
    """A stale pilot is read by no reported number: a note with its remedy, which does not fail
    `verify --strict` (issue 34 case 11: it did, as a warning)."""
    report = verify(piloted)
    assert report.ok, report.format()
    assert not [w for w in report.warnings if w.startswith("development output")], report.format()
    stale = [n for n in report.notes if n.startswith("development output stale")]
    assert all("`snakemake -c2 pilot` or `dev` rebuilds it" in n for n in stale)
    assert "note     development output stale" in report.format()
    # fast's shards, table, nominal episode and the rates
    assert len(stale) == 3 + 2 + 1, report.format()
    assert report.status_of(f"{DEVELOPMENT.rollout_table('slow').as_posix()}") is Status.OK

    # a current pilot output is checked as any: slow's gathered table, a success flipped
    # under its old stamp, is tampered (its re-simulated sample says so too)
    work = tmp_path / "experiment"
    shutil.copytree(piloted, work, symlinks=True)
    path = work / DEVELOPMENT.rollout_table("slow")
    stamp, table = provenance.read_stamp(path), pq.read_table(path)
    success = table.column("success").to_pylist()
    success[0] = not success[0]
    table = table.set_column(table.schema.get_field_index("success"), "success", pa.array(success))
    provenance.write_parquet(table.replace_schema_metadata(None), path, stamp)
    report = verify(work)
    assert not report.ok
    assert report.with_status(Status.TAMPERED) == [DEVELOPMENT.rollout_table("slow").as_posix()]


def test_the_analysis_refuses_development_states_and_a_pilot_table(piloted, tmp_path):
    config = yaml.safe_load((piloted / "config" / "config.yaml").read_text())
    kwargs = dict(
        states_path=piloted / LAYOUT.states,
        rollout_tables={c: piloted / LAYOUT.rollout_table(c) for c in ("fast", "slow")},
        nominal_files={c: piloted / LAYOUT.nominal_episode(c) for c in ("fast", "slow")},
        analysis_slice=config_slice("analysis", config),
        output=tmp_path / "summary.json",
        repo_root=piloted,
    )
    with pytest.raises(ValueError, match="not evaluation states; the analysis reads"):
        run_analysis(**{**kwargs, "states_path": piloted / DEVELOPMENT.states})
    pilot_tables = {c: piloted / DEVELOPMENT.rollout_table(c) for c in ("fast", "slow")}
    with pytest.raises(ValueError, match="'pilot_gather:fast', not the evaluation's gather"):
        run_analysis(**{**kwargs, "rollout_tables": pilot_tables})
    assert not (tmp_path / "summary.json").exists()
    run_analysis(**kwargs)  # the evaluation's own inputs


def swap_seeds(config: dict) -> None:
    states = config["states"]
    states["seed"], states["development_seed"] = states["development_seed"], states["seed"]


def test_evaluation_states_a_pilot_ran_are_refused_and_fail_verify(piloted, tmp_path):
    """Issue 34 case 4: seeds swapped after a pilot made the evaluation states the pilot's
    tuning states, and verify said "verified". A pilot's states stay development states."""
    work = tmp_path / "experiment"
    shutil.copytree(piloted, work, symlinks=True)
    config = yaml.safe_load((work / "config" / "config.yaml").read_text())
    swap_seeds(config)
    output = work / "swapped" / "states.parquet"  # beside a copy of the pilot's development/
    shutil.copytree(work / DEVELOPMENT.root, output.parent / "development", symlinks=True)
    with pytest.raises(ValueError) as err:
        build_states(states_slice=config_slice("states", config), output=output, repo_root=work)
    message = str(err.value)
    assert "\n" not in message and not output.exists()
    assert message.startswith("states.seed: 12 of the 12 evaluation states are states the pilot")
    assert "development_seed 7" in message and "expected a states.seed drawing other" in message
    # unswapped, the same stage draws the evaluation states as before
    config = yaml.safe_load((work / "config" / "config.yaml").read_text())
    drawn = build_states(states_slice=config_slice("states", config), output=output, repo_root=work)
    assert drawn.equals(pq.read_table(work / LAYOUT.states))

    # the other way round: a pilot run on the evaluation states (seeds swapped for the pilot
    # only); the run's evaluation states are now tuning states, and verify fails the run
    edit_config(work, swap_seeds)
    run_snakemake(work, "pilot", "--config", PILOT_CONFIG)
    edit_config(work, swap_seeds)
    development = pq.read_table(work / DEVELOPMENT.states)
    assert development.equals(pq.read_table(work / LAYOUT.states))
    report = verify(work)
    assert not report.ok, report.format()
    assert report.with_status(Status.STALE) == [LAYOUT.states.as_posix()], report.format()
    (line,) = [o.line() for o in report.outputs if o.path == LAYOUT.states.as_posix()]
    assert "12 of the 12 evaluation states are states the pilot tuned on" in line
    assert f"({DEVELOPMENT.states.as_posix()}, development_seed 2026)" in line
