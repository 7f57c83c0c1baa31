"""`mjtrial new-task`: the scaffold runs end to end as generated (main target, studies, verify),
its report speaks its own words, and bad task code in it stops the run with one line before
any rollout, leaving the results as they were."""

from __future__ import annotations

import hashlib
import re
import shutil
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT, WORKFLOW_FILES, error_lines, run_snakemake

from mjtrial.cli import main
from mjtrial.cli.scaffold import ScaffoldError, new_task

pytestmark = pytest.mark.end_to_end

NAME = "push_block"
CONFIG = f"config/{NAME}.yaml"


def _digest(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def scaffolded(tmp_path_factory) -> Path:
    """A copy of the repository with `mjtrial new-task push_block`, built small (12 states in
    shards of 6), studies included."""
    workdir = tmp_path_factory.mktemp("scaffold")
    for name in WORKFLOW_FILES:
        src = REPO_ROOT / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, workdir / name)
    assert main(["new-task", NAME, "--repo-root", str(workdir)]) == 0
    path = workdir / CONFIG
    config = yaml.safe_load(path.read_text())
    config["states"]["n"] = 12
    config["rollout"]["shard_size"] = 6
    config["analysis"]["n_resamples"] = 300
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    run_snakemake(workdir, "--configfile", CONFIG)
    run_snakemake(workdir, "studies", "--configfile", CONFIG)
    return workdir


def test_new_task_writes_a_task_folder_and_a_config(tmp_path):
    written = new_task("slide_test", repo_root=tmp_path)
    assert [p.relative_to(tmp_path).as_posix() for p in written] == [
        "tasks/slide_test/task.py",
        "tasks/slide_test/model.xml",
        "config/slide_test.yaml",
    ]
    config = yaml.safe_load(written[2].read_text())
    assert config["experiment"] == "slide_test"
    assert config["task"] == "tasks/slide_test/task.py"
    assert 'name="slide_test"' in written[0].read_text()
    assert "CHANGE" in written[0].read_text()


@pytest.mark.parametrize("name", ["Push", "1push", "push-block", "push block", ""])
def test_new_task_refuses_a_name_that_is_not_an_identifier(tmp_path, name):
    with pytest.raises(ScaffoldError, match="expected a lower-case name"):
        new_task(name, repo_root=tmp_path)
    assert not any(tmp_path.iterdir())


def test_new_task_overwrites_nothing(tmp_path, capsys):
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "mine.yaml").write_text("experiment: mine\n")
    assert main(["new-task", "mine", "--repo-root", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("config/mine.yaml: exists; nothing written") and "\n" not in err
    assert not (tmp_path / "tasks").exists()
    assert (tmp_path / "config" / "mine.yaml").read_text() == "experiment: mine\n"


def test_the_scaffold_runs_its_studies_and_verifies(scaffolded):
    from mjtrial.verify import verify_results

    results = scaffolded / "results" / NAME
    for name in ("report.md", "seal.json", "report_dose_response.md", "report_sensitivity.md"):
        assert (results / name).is_file(), name
    report = verify_results(
        results, config_path=scaffolded / CONFIG, repo_root=scaffolded, resimulate=2
    )
    assert report.exit_code == 0, report.format()
    for target in ((), ("studies",)):
        plan = run_snakemake(scaffolded, *target, "-n", "--configfile", CONFIG).stdout
        assert "Nothing to be done" in plan, plan


def test_the_scaffold_report_speaks_its_own_words(scaffolded):
    text = (scaffolded / "results" / NAME / "report.md").read_text().lower()
    assert "block" in text and "push_force" in text
    for word in ("cube", "gripper", "lift_time", "gantry"):
        assert word not in text.split("## reproduction")[0].split("\n---\n", 1)[-1], word


@pytest.mark.parametrize(
    ("case", "edit", "message"),
    [
        (
            "success of a wrong shape",
            lambda t: t.replace(
                "return np.abs(_position(episodes)[:, -1] - TARGET) < TOLERANCE",
                "return np.abs(_position(episodes) - TARGET) < TOLERANCE",
            ),
            r"success: expected an array of shape \(1,\)",
        ),
        (
            "an exception in controls",
            lambda t: t.replace('params["push_force"]', 'params["push_forc"]'),
            "controls raised KeyError",
        ),
        (
            "non-finite controls",
            lambda t: t.replace(
                '] = params["push_force"]', '] = params["push_force"] * float("nan")'
            ),
            "controls: non-finite values",
        ),
        (
            "a state parameter never applied",
            lambda t: t.replace("JointPosition(SLIDE)", "Custom(lambda m, d, v: None)").replace(
                "    BodyMass,\n", "    BodyMass,\n    Custom,\n"
            ),
            "state parameter 'start': the episode is the same at its low and high values",
        ),
    ],
    ids=lambda c: c if isinstance(c, str) else None,
)
def test_bad_task_code_stops_with_one_line_and_touches_nothing(
    scaffolded, tmp_path, case, edit, message
):
    workdir = tmp_path / "copy"
    shutil.copytree(scaffolded, workdir, symlinks=True)
    task = workdir / "tasks" / NAME / "task.py"
    task.write_text(edit(task.read_text()))
    before = _digest(workdir / "results")
    proc = run_snakemake(workdir, "--configfile", CONFIG, check=False)
    assert proc.returncode != 0
    lines = error_lines(proc)
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"Config error: {CONFIG}: task: ")
    assert f"tasks/{NAME}/task.py" in lines[0]
    assert re.search(message, lines[0]), lines[0]
    assert _digest(workdir / "results") == before
