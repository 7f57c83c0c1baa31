"""Nothing lost, nothing unnoticed: a job that fails at run time leaves the results from before
it byte for byte; every log is stamped and holds the error; `verify` sees an edit to any
output; `mjtrial replay` writes over nothing it did not write."""

from __future__ import annotations

import hashlib
import shutil
import subprocess
from io import BytesIO
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from conftest import SNAKEMAKE, run_snakemake
from PIL import Image

from mjtrial import cli, provenance
from mjtrial.files.layout import Layout
from mjtrial.replay import OutputRefused, check_output, replay_episode
from mjtrial.verify import Status, verify_results

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")
SHARD_SIZE = 5  # the built experiment's rollout.shard_size (conftest)


def digest(folder: Path) -> dict[str, str]:
    """sha256 of every file under `folder` except the logs and hidden files."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
        and "logs" not in p.parts
        and not any(part.startswith(".") for part in p.relative_to(folder).parts)
    }


@pytest.fixture
def work(built, tmp_path) -> Path:
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    return workdir


def _garbage_states(workdir: Path) -> None:
    """The rollouts' input replaced by garbage, its stage's params untouched: the rollouts run
    (forced) and fail at run time."""
    (workdir / LAYOUT.states).write_bytes(b"not a parquet file")


def _truncated_recording(workdir: Path) -> None:
    table = pq.read_table(workdir / LAYOUT.rollout_table("fast"))
    failed = [r["state_id"] for r in table.to_pylist() if not r["success"]]
    shard = LAYOUT.shard_recordings("fast", f"{failed[0] // SHARD_SIZE:05d}")
    episode = workdir / shard / f"fast-state-{failed[0]:06d}.rrd"
    episode.write_bytes(episode.read_bytes()[:100])


# (case, how to break the run, the Snakemake arguments, what the job's log must say)
RUNTIME_FAILURES = [
    (
        "garbage states table",
        _garbage_states,
        ("--forcerun", "rollout"),
        "error: rollout:",
    ),
    (
        "truncated episode recording",
        _truncated_recording,
        ("--forcerun", "failures"),
        "error: failures:",
    ),
]


@pytest.mark.parametrize(
    ("case", "breaks", "args", "logged"), RUNTIME_FAILURES, ids=[c[0] for c in RUNTIME_FAILURES]
)
def test_a_job_failing_at_run_time_loses_no_result(work, case, breaks, args, logged):
    breaks(work)
    before = digest(work / "results")
    proc = run_snakemake(work, *args, check=False)
    assert proc.returncode != 0
    assert "mjtrial: a job failed; the previous results were put back unchanged" in proc.stderr
    assert digest(work / "results") == before
    # The console ends on the failed job's reason, read back from its log (not only Snakemake's
    # "At least one job did not complete successfully").
    tail = proc.stderr.split("the previous results were put back unchanged", 1)[1]
    assert any(
        line.startswith(logged) and f"(its log: {LAYOUT.logs_dir}/" in line
        for line in tail.splitlines()
    ), proc.stderr
    # The failed job's log: its stamp first, then the one-line error, then the traceback.
    logs = sorted((work / LAYOUT.logs_dir).glob("*.log"), key=lambda p: p.stat().st_mtime)
    text = logs[-1].read_text()
    assert logged in text, text
    assert "Traceback" in text.split(logged, 1)[1]
    assert str(work) not in text  # paths relative to the working folder (survey 2, minor)
    assert provenance.read_stamp(logs[-1])["rule"].split(":")[0] in ("rollout", "failures")
    # A later run with the cause gone rebuilds; the results are then complete and verified.
    assert not (work / LAYOUT.root / ".snapshot").exists()


def test_every_log_begins_with_its_stamp(built):
    logs = sorted((built / LAYOUT.logs_dir).glob("*.log"))
    assert {p.stem for p in logs} >= {
        "states",
        *(f"rollout_{c}_{s}" for c in ("fast", "slow") for s in ("00000", "00001", "00002")),
        "gather_fast",
        "gather_slow",
        "failures",
        "analysis",
        "figures",
        "manifest",
        "report",
        "seal",
    }
    for log in logs:
        stamp = provenance.read_stamp(log)
        assert stamp["rule"].split(":")[0] == log.stem.split("_")[0]
        assert stamp["extra"]["code"]


def test_every_log_holds_its_own_jobs_messages_and_ends_with_its_resources(built):
    """The jobs after the rollouts run side by side in Snakemake's process (a gather beside
    the other): each log still holds its own messages only, and ends with the job's resources;
    a rollout's and the failures job's are their own process's."""
    for log in sorted((built / LAYOUT.logs_dir).glob("*.log")):
        lines = log.read_text(encoding="utf-8").splitlines()
        rule = provenance.read_stamp(log)["rule"]
        assert lines[-1].startswith("# resources: wall "), log.name
        in_process = "in snakemake's process" in lines[-1]
        assert in_process == (not log.stem.startswith(("rollout_", "failures"))), log.name
        stage = rule.split(":")[0]
        others = {"states", "rollout", "gather", "failures", "analysis", "manifest", "report"}
        others |= {"figures", "seal", "crate"}
        for line in lines[1:-1]:  # no line of another job: those begin "<stage>:" or "<stage> ->"
            word = line.split(" ")[0].split(":")[0]
            assert word not in others - {stage}, (log.name, line)
        assert any(line.split(" ")[0].split(":")[0] == stage for line in lines[1:-1]), log.name


def test_temporaries_of_a_killed_job_are_removed_by_the_next_run(work):
    left = work / LAYOUT.recordings("slow") / ".shard-00000.tmp-123-abcd"
    left.mkdir()
    (left / "slow-state-000001.rrd").write_bytes(b"half")
    proc = run_snakemake(work, "--forcerun", "seal")
    assert not left.exists()
    assert f"removed {LAYOUT.root}/rollouts/slow/.shard-00000.tmp-123-abcd" in proc.stderr


# --------------------------------------------------------------------------------------------
# verify sees an edit to any output
# --------------------------------------------------------------------------------------------


def _edit_report(workdir: Path) -> Path:
    path = workdir / LAYOUT.report
    text = path.read_text()
    number = next(w for w in text.split() if w[:2] == "0." and w[2:3].isdigit())
    path.write_text(text.replace(number, "0.999", 1))
    return path


def _edit_png_pixels(workdir: Path) -> Path:
    """Pixels changed, the image re-saved with its text chunks (the stamp) kept."""
    path = workdir / LAYOUT.figure("success_by_condition", "png")
    image = Image.open(path)
    info = image.info
    image = image.convert("RGBA")
    image.putpixel((5, 5), (255, 0, 0, 255))
    from PIL.PngImagePlugin import PngInfo  # noqa: PLC0415 - test-only helper

    chunks = PngInfo()
    for key, value in info.items():
        if isinstance(value, str):
            chunks.add_text(key, value)
    buffer = BytesIO()
    image.save(buffer, format="png", pnginfo=chunks)
    path.write_bytes(buffer.getvalue())
    assert provenance.read_stamp(path)["rule"] == "figures"
    return path


def _edit_svg_path(workdir: Path) -> Path:
    path = workdir / LAYOUT.figure("paired_outcomes", "svg")
    text = path.read_text()
    start = text.index(' d="M ') + len(' d="M ')
    path.write_text(text[:start] + "1" + text[start:])
    return path


@pytest.mark.parametrize("edit", [_edit_report, _edit_png_pixels, _edit_svg_path])
def test_verify_names_an_edited_report_or_figure(work, edit):
    path = edit(work)
    report = verify_results(
        work / LAYOUT.root, config_path=work / "config" / "config.yaml", repo_root=work
    )
    rel = path.relative_to(work).as_posix()
    assert report[rel].status is Status.TAMPERED, report.format()
    # the seal records its sha256 (and, for a figure, the report that shows it)
    assert "seal.json does not match" in " ".join(report[rel].reasons)
    assert not report.ok


def test_verify_calls_a_missing_seal_missing(work):
    (work / LAYOUT.seal).unlink()
    report = verify_results(
        work / LAYOUT.root, config_path=work / "config" / "config.yaml", repo_root=work
    )
    assert report[(LAYOUT.seal).as_posix()].status is Status.MISSING


# --------------------------------------------------------------------------------------------
# mjtrial replay writes over nothing it did not write
# --------------------------------------------------------------------------------------------


def test_replay_refuses_to_write_over_pipeline_files(work, capsys, monkeypatch):
    results = work / LAYOUT.root
    before = digest(work / "results")
    for target in [
        LAYOUT.states,
        LAYOUT.failures,
        LAYOUT.rollout_table("fast"),
        LAYOUT.shard_recordings("fast", "00000") / "new.rrd",
        LAYOUT.shard_table("fast", "00001"),
        LAYOUT.failures_table,
        LAYOUT.root / "new.json",
    ]:
        with pytest.raises(OutputRefused, match="--output"):
            check_output(work / target, results=results, force=True)
    monkeypatch.chdir(work)  # the command works in the repository it is run from
    code = cli.main(
        [
            "replay",
            "--condition",
            "fast",
            "--state",
            "0",
            "--no-viewer",
            "--output",
            str(LAYOUT.states),
        ]
    )
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "inside the results folder" in err[0]
    assert digest(work / "results") == before


def test_replay_overwrites_only_its_own_files_or_with_force(work, tmp_path):
    mine = work / LAYOUT.root / "replay" / "mine.rrd"
    replay_episode(condition="fast", state_id=0, output=mine, repo_root=work)
    replay_episode(condition="fast", state_id=0, output=mine, repo_root=work)  # its own: fine
    other = tmp_path / "notes.rrd"
    other.write_text("someone's file")
    with pytest.raises(OutputRefused, match="pass --force"):
        replay_episode(condition="fast", state_id=0, output=other, repo_root=work)
    assert other.read_text() == "someone's file"
    replay_episode(condition="fast", state_id=0, output=other, repo_root=work, force=True)
    assert provenance.read_stamp(other)["rule"] == "replay"


# --------------------------------------------------------------------------------------------
# Command-line overrides
# --------------------------------------------------------------------------------------------


def test_a_nested_config_override_is_read_as_yaml(work):
    proc = run_snakemake(work, "-n", "--config", "states={n: 13}")
    assert "states" in proc.stdout
    bad = subprocess.run(
        [SNAKEMAKE, "-c2", "-n", "--config", "states={n: 13.5}"],
        cwd=work,
        capture_output=True,
        text=True,
    )
    assert bad.returncode != 0
    assert "Config error: --config: states.n: expected integer, got 13.5" in bad.stderr
