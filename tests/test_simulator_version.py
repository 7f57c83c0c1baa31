"""Another MuJoCo version as a simulator variant: its environment built by the workflow with
uv (offline once cached), its rollouts run there and stamped so, judged like every variant,
its flipped episodes in the report.

The environment's build needs uv's cache: `UV_CACHE_DIR` where it is set (CI keeps one between
runs), else `envs/uv-cache` in the checkout (git ignores it). A cold cache downloads about
80 wheels once (13 s here); a warm one builds offline in about 3 s.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT, edit_config, run_snakemake
from test_verify_recompute import nudge_final_x

from mjtrial import provenance
from mjtrial.config import ConfigError, check_config
from mjtrial.files.layout import NOMINAL, Layout
from mjtrial.studies.sensitivity import flipped_episodes
from mjtrial.verify import Status, verify_results

pytestmark = pytest.mark.end_to_end

VERSION = "4.0.0"
LOCK = Path("envs") / f"mujoco-{VERSION}" / "lock.txt"
LAYOUT = Layout.of("research_mode")
CACHE = {"UV_CACHE_DIR": os.environ.get("UV_CACHE_DIR", str(REPO_ROOT / "envs" / "uv-cache"))}


@pytest.fixture(scope="module")
def versioned(built, tmp_path_factory) -> Path:
    """The small experiment with a variant on MuJoCo 4.0.0: its sensitivity study."""
    workdir = tmp_path_factory.mktemp("version") / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    edit_config(workdir, lambda c: c.update(variants={"mujoco_4": {"mujoco": VERSION}}))
    run_snakemake(workdir, "sensitivity", env=CACHE)
    return workdir


def test_the_variant_runs_in_its_own_environment_and_its_stamps_say_so(versioned):
    lock = versioned / LOCK
    assert f"mujoco=={VERSION} " in lock.read_text()
    sha = provenance.file_sha256(lock)
    falsifier = yaml.safe_load((versioned / "config" / "config.yaml").read_text())["design"]
    for condition in (falsifier["falsifier"]["treatment"], falsifier["falsifier"]["baseline"]):
        table = versioned / LAYOUT.rollout_table(condition, "mujoco_4")
        nominal = versioned / LAYOUT.rollout_table(condition)
        shard = versioned / LAYOUT.shard_table(condition, "00000", "mujoco_4")
        for path in (table, shard):
            stamp = provenance.read_stamp(path)
            assert stamp["versions"]["mujoco"] == VERSION
            assert stamp["inputs"]["simulator_env"] == {"path": LOCK.as_posix(), "sha256": sha}
        assert provenance.read_stamp(nominal)["versions"]["mujoco"] == mujoco.__version__
    # the crate's copy of what the run read holds the lock
    assert (versioned / LAYOUT.root / "source" / LOCK).read_bytes() == lock.read_bytes()


def test_the_report_lists_the_states_whose_outcome_flipped(versioned):
    summary = json.loads((versioned / LAYOUT.study_summary("sensitivity")).read_text())
    record = summary["variants"]["mujoco_4"]
    assert record["overrides"] == {"mujoco": VERSION}
    flips, compared = [], 0
    for condition in record["conditions"]:  # an independent count from the two tables
        a = pq.read_table(versioned / LAYOUT.rollout_table(condition)).to_pydict()
        b = pq.read_table(versioned / LAYOUT.rollout_table(condition, "mujoco_4")).to_pydict()
        compared += len(a["state_id"])
        pairs = zip(a["state_id"], a["success"], b["success"], strict=True)
        flips += [(condition, i) for i, x, y in pairs if x != y]
    assert record["flipped"]["n_compared"] == compared == 2 * 12
    assert [(e["condition"], e["state_id"]) for e in record["flipped"]["episodes"]] == flips
    report = (versioned / LAYOUT.study_report("sensitivity")).read_text()
    assert f"Flipped episodes under mujoco_4: {len(flips)} of {compared}" in report
    assert f"mujoco_4: MuJoCo {VERSION}, in an environment of its own" in report
    assert NOMINAL not in record["flipped"]


# A variant on MuJoCo 4.0.0 with slipperier pads and cube (a contact takes the larger of its
# two geoms' friction): 3 of the 12 fast lifts flip, so the report's table has rows, each with
# where the two trajectories part.
SLIPPERY = {
    "mujoco": VERSION,
    "geom": {g: {"friction": [0.5, 0.003, 0.0001]} for g in ("left_pad", "right_pad", "cube")},
}


@pytest.fixture(scope="module")
def slippery(versioned, tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("slippery") / "copy"
    shutil.copytree(
        versioned, workdir, symlinks=True, ignore=lambda d, _: ["envs"] * (d == str(versioned))
    )
    (workdir / "envs").symlink_to(versioned / "envs", target_is_directory=True)
    edit_config(workdir, lambda c: c["variants"].update(slippery=SLIPPERY))
    run_snakemake(workdir, "sensitivity", env=CACHE)
    return workdir


def first_parting(a: dict, b: dict, tolerance: float = 1e-6) -> tuple[float, int] | None:
    """A plain reference: walk the times both recordings logged, in order, and return the
    first (time, step of a) at which any value they share differs by more than `tolerance`."""
    index_b = {round(float(t) * 1e9): j for j, t in enumerate(b["time"])}
    keys = sorted(set(a) & set(b) - {"time", "step"})
    for i, t in enumerate(a["time"]):
        j = index_b.get(round(float(t) * 1e9))
        if j is None:
            continue
        for key in keys:
            x, y = np.ravel(a[key][i]).astype(float), np.ravel(b[key][j]).astype(float)
            if x.shape == y.shape and any(
                abs(p - q) > tolerance or (np.isnan(p) != np.isnan(q))
                for p, q in zip(x, y, strict=True)
            ):
                return float(t), int(a["step"][i])
    return None


def test_the_flipped_episodes_say_where_their_trajectories_part(slippery):
    """As `mjtrial diff` does between two runs: each flipped episode's first logged time at
    which the nominal model's recording and the variant's differ, checked against a plain walk
    over both recordings; the report's table shows it, and verify recomputes it."""
    from mjtrial.recording import find_episode_file, read_episode

    summary = json.loads((slippery / LAYOUT.study_summary("sensitivity")).read_text())
    episodes = summary["variants"]["slippery"]["flipped"]["episodes"]
    assert episodes, "the slippery pads flip no outcome: the test needs one"
    report = (slippery / LAYOUT.study_report("sensitivity")).read_text()
    assert "| state | condition | nominal | slippery | where the trajectories part |" in report
    for e in episodes:
        condition, sid = e["condition"], e["state_id"]
        series = [
            read_episode(
                find_episode_file(
                    slippery / LAYOUT.recordings(condition, v), condition=condition, state_id=sid
                ),
                condition=condition,
                state_id=sid,
            )
            for v in (NOMINAL, "slippery")
        ]
        time, step = first_parting(*series)
        d = e["divergence"]
        assert d["time"] == pytest.approx(time, abs=1e-9) and d["step"][0] == step, (e, time)
        assert f"| {sid} | {condition} | " in report and f"t = {time:.4f} s" in report
    verify = verified(slippery, resimulate=1)
    assert verify.ok, verify.format()


def test_the_environment_builds_again_offline_from_the_cache(versioned, tmp_path):
    """A copy of the run without its environment's folder (not copied, then removed: its venv
    is 1.3 GB)."""
    workdir = copy_of(versioned, tmp_path / "copy", env="absent")
    lock = (versioned / LOCK).read_text()
    assert not (workdir / LOCK.parent).exists()
    run_snakemake(workdir, str(LOCK), env={**CACHE, "UV_OFFLINE": "1"})
    assert (workdir / LOCK).read_text() == lock


def verified(workdir: Path, **kwargs):
    config = workdir / "config" / "config.yaml"
    return verify_results(workdir / LAYOUT.root, config_path=config, repo_root=workdir, **kwargs)


def copy_of(versioned: Path, workdir: Path, *, env: str) -> Path:
    """A copy of the run; its environment's folder `linked` to the original (not copied: 1.3
    GB), `absent`, or holding only its lock (`no venv`) or a lock with a line added."""
    top = str(versioned)
    shutil.copytree(versioned, workdir, symlinks=True, ignore=lambda d, _: ["envs"] * (d == top))
    if env == "linked":
        (workdir / "envs").symlink_to(versioned / "envs", target_is_directory=True)
    elif env != "absent":
        (workdir / LOCK).parent.mkdir(parents=True)
        text = (versioned / LOCK).read_text()
        (workdir / LOCK).write_text(text if env == "no venv" else text + "# edited\n")
    return workdir


def test_verify_resimulates_the_variant_in_its_environment(versioned):
    """Both conditions' every episode (shards of 5, `resimulate` 5) and nominal episode, on
    MuJoCo 4.0.0: this MuJoCo's measures differ from it (the nominal tables), so only a
    re-simulation in the variant's environment agrees with its tables."""
    here, there = (
        pq.read_table(versioned / LAYOUT.rollout_table("fast", v)).column("final_x")
        for v in (NOMINAL, "mujoco_4")
    )
    assert here != there
    report = verified(versioned, resimulate=5, seed=1)
    assert report.ok, report.format()
    [line] = report.checks
    assert "and re-simulated 48 of 48 episodes (sample seed 1" in line  # 2 x 12 in each variant
    assert line.endswith(f"0 differ; re-simulated mujoco_4/fast, mujoco_4/slow in {LOCK.parent}")


def test_an_episode_of_the_variant_forged_and_rebuilt_downstream_is_named(versioned, tmp_path):
    """Nudge a measure its recording does not carry in one of the variant's shards, under its
    own stamp, and let Snakemake rebuild what follows: every stamp, seal and recording agrees;
    the re-simulation in the variant's environment does not."""
    workdir = copy_of(versioned, tmp_path / "copy", env="linked")
    shard = workdir / LAYOUT.shard_table("slow", "00001", "mujoco_4")
    nudge_final_x(shard, row=2)  # state 7
    run_snakemake(workdir, "sensitivity", env=CACHE)

    report = verified(workdir, resimulate=5)
    rel = shard.relative_to(workdir).as_posix()
    assert report[rel].status is Status.TAMPERED, report.format()
    assert "re-simulated episodes for states 7 differ in final_x" in " ".join(report[rel].reasons)


@pytest.mark.parametrize(
    ("env", "why"),
    [
        ("absent", f"{LOCK.parent} not built; `snakemake -c2 {LOCK}` builds it"),
        ("edited", f"the lock in {LOCK.parent} differs from the one the run used"),
        (
            "no venv",
            f"{LOCK.parent} has no venv/bin/python: remove the folder, and `snakemake -c2 {LOCK}` "
            "builds it",
        ),
    ],
)
def test_verify_says_why_it_did_not_resimulate_the_variant(versioned, tmp_path, env, why):
    workdir = copy_of(versioned, tmp_path / "copy", env=env)
    report = verified(workdir, resimulate=1)
    [line] = report.checks
    assert line.endswith(f"0 differ; not re-simulated: mujoco_4/fast, mujoco_4/slow ({why})")
    table = LAYOUT.rollout_table("fast", "mujoco_4").as_posix()
    # without its environment's lock, or with another, the variant's tables are stale
    assert report[table].status is (Status.OK if env == "no venv" else Status.STALE)
    assert report.unchecked == (f"mujoco_4/fast, mujoco_4/slow not re-simulated ({why})",)
    assert report.ok is (env == "no venv") and not report.complete


def test_verify_strict_fails_what_it_could_not_check(versioned, tmp_path, capsys):
    """`--strict`, for a CI gate: a run whose environment holds its lock but no interpreter
    passes plain verify (every stamp holds, the test above) but fails strict verify, naming why
    it re-simulated nothing there; with the environment, strict verify passes."""
    from mjtrial.cli import main

    def verify(workdir: Path, *strict: str) -> int:
        return main(
            [
                "verify",
                str(workdir / LAYOUT.root),
                "--repo-root",
                str(workdir),
                "--resimulate",
                "1",
                *strict,
            ]
        )

    unbuilt = copy_of(versioned, tmp_path / "unbuilt", env="no venv")
    assert verify(unbuilt, "--strict") == 1
    err = capsys.readouterr().err
    assert err.startswith("mjtrial verify --strict: not verified: 1 warnings or checks not done")
    assert "mujoco_4/fast, mujoco_4/slow not re-simulated (envs/mujoco-4.0.0 has no venv" in err
    linked = copy_of(versioned, tmp_path / "linked", env="linked")
    assert verify(linked, "--strict") == 0, capsys.readouterr()


def test_flipped_episodes_pairs_the_states_both_ran():
    nominal = {
        "a": {
            "state_id": np.array([0, 1, 2, 3]),
            "success": np.array([True, False, True, False]),
            "failure_category": np.array(["", "dropped", "", "missed"], dtype=object),
        }
    }
    variant = {
        "a": {
            "state_id": np.array([1, 2, 3]),
            "success": np.array([True, False, False]),
            "failure_category": np.array(["", "slipped", "missed"], dtype=object),
        }
    }
    assert flipped_episodes(nominal, variant) == {
        "n_compared": 3,
        "episodes": [
            {"condition": "a", "state_id": 1, "nominal": "dropped", "variant": ""},
            {"condition": "a", "state_id": 2, "nominal": "", "variant": "slipped"},
        ],
    }


@pytest.mark.parametrize(
    ("version", "message"),
    [
        (
            mujoco.__version__,
            f"{mujoco.__version__} is the MuJoCo that runs; expected another version",
        ),
        (4.0, "expected string, got 4.0"),
        ("4.0", r"expected a name matching ^\d+\.\d+\.\d+$, got '4.0'"),
    ],
)
def test_a_version_variant_is_checked_before_work(version, message):
    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    config["variants"] = {"other": {"mujoco": version}}
    with pytest.raises(ConfigError) as err:
        check_config(config, source="config/config.yaml", repo_root=REPO_ROOT)
    assert str(err.value) == f"config/config.yaml: variants.other.mujoco: {message}"
