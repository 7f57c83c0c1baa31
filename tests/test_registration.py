"""The registered design (mjtrial.design.registration): frozen at the first run, never rewritten by
a rerun, every later difference recorded as a deviation, with whether results existed."""

from __future__ import annotations

import base64
import copy
import hashlib
import json
import shutil
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, edit_config, run_snakemake

from mjtrial import cli, provenance
from mjtrial.design import registration
from mjtrial.diff import diff_runs, render
from mjtrial.files.layout import Layout
from mjtrial.report.registration import falsifier_clause, registration_lines
from mjtrial.verify import Status, verify_results

pytestmark = pytest.mark.end_to_end

RESULTS = "results/research_mode"


@pytest.fixture
def config():
    return yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())


def test_register_keeps_every_earlier_registration(tmp_path, config):
    layout = Layout(tmp_path / "results" / "x")
    first = registration.register(config, layout=layout, repo_root=REPO_ROOT)
    assert first["current"]["design"]["sections"]["conditions"] == config["conditions"]
    with pytest.raises(registration.RegistrationError, match="already registered on .*--again"):
        registration.register(config, layout=layout, repo_root=REPO_ROOT)
    changed = copy.deepcopy(config)
    changed["design"]["falsifier"]["threshold"] = 0.05
    again = registration.register(
        changed, layout=layout, repo_root=REPO_ROOT, again=True, reason="pilot"
    )
    assert again["earlier"][0]["design"] == first["current"]["design"]
    assert again["earlier"][0]["superseded_utc"] == again["current"]["registered_utc"]
    data = registration.read(layout.registration)
    assert registration.problems(data) == []
    assert registration.deviations(data, registration.design_record(config)) == [
        {"key": "design.falsifier.threshold", "registered": 0.05, "now": 0.0}
    ]


def test_a_tampered_registration_names_what_was_changed(tmp_path, config):
    layout = Layout(tmp_path / "results" / "x")
    registration.register(config, layout=layout, repo_root=REPO_ROOT)
    data = registration.read(layout.registration)
    data["current"]["design"]["sections"]["states"]["n"] = 100
    assert registration.problems(data) == [
        "the registration: its design is not the one its sha256 was taken of",
        "the registration: it is not the one its sha256 was taken of",
        "the registration history is not the one its sha256 was taken of",
    ]


def test_deviations_name_added_and_removed_keys(config):
    now = copy.deepcopy(config)
    now["stopping"] = {"rule": "e-process"}
    del now["failure_taxonomy"]["max_tilt"]
    found = registration.changes(config, now)
    assert {
        "key": "failure_taxonomy.max_tilt",
        "registered": 1.0,
        "now": None,
        "absent": "now",
    } in found
    assert {
        "key": "stopping",
        "registered": None,
        "now": {"rule": "e-process"},
        "absent": "registered",
    } in found


def _manifest(**record):
    base = {
        "path": f"{RESULTS}/registration.json",
        "registered_utc": "2026-01-01T10:00:00Z",
        "design_sha256": "ab" * 32,
        "before_any_rollout": True,
        "deviations": [],
        "deviation_noted": None,
        "earlier": [],
        "plan": None,
    }
    stamps = {
        f"{RESULTS}/rollouts/fast/shard-00000.parquet": {
            "rule": "rollout:fast#00000",
            "created_utc": "2026-01-01T10:00:05Z",
        }
    }
    return {"registration": {**base, **record}, "stamps": stamps}


def test_the_report_says_before_any_rollout_only_when_true():
    summary = {"falsifier": {"verdict": "refuted"}}
    assert falsifier_clause(_manifest()).startswith("Registered on 2026-01-01 10:00:00 UTC, before")
    late = _manifest(before_any_rollout=False)
    assert "after rollouts existed (the first on 2026-01-01 10:00:05 UTC)" in falsifier_clause(late)
    change = {"key": "design.falsifier.threshold", "registered": 0.0, "now": 0.05}
    noted = {
        "first_run_utc": "2026-01-02T09:00:00Z",
        "results_existed": True,
        "of_registered_design": True,
        "verdict": "refuted",
    }
    deviated = _manifest(deviations=[change], deviation_noted=noted)
    assert "before any rollout" not in falsifier_clause(deviated)
    text = "\n".join(registration_lines(deviated, summary))
    assert "| `design.falsifier.threshold` | `0.0` | `0.05` |" in text
    assert "when results existed: a summary of the registered design (verdict REFUTED)" in text
    assert falsifier_clause({}).startswith("Not registered")


def test_a_run_registers_and_an_edit_after_the_results_is_a_deviation(tmp_path, monkeypatch):
    """End to end: the first run registers before any rollout; an edit of the falsifier's
    threshold and of a condition after the results exist, run with --forceall, leaves the
    registration as it was and records the deviation with the results that existed; verify
    checks it and sees tampering; re-registering keeps the earlier one; the diff of the two
    runs shows the registration first."""
    (tmp_path / "experiment").mkdir()
    work = copy_workflow(tmp_path / "experiment")

    def small(config):
        config["states"]["n"] = 10
        config["rollout"]["shard_size"] = 10
        config["analysis"]["n_resamples"] = 200
        config["recording"]["episodes"] = "none"

    edit_config(work, small)
    run_snakemake(work)
    results = work / RESULTS
    registered = (results / "registration.json").read_bytes()
    manifest = json.loads((results / "manifest.json").read_text())["registration"]
    assert manifest["before_any_rollout"] and manifest["deviations"] == []
    report = (results / "report.md").read_text()
    assert "before any rollout" in report and "Written before the data" not in report
    first_run = tmp_path / "first" / "research_mode"
    shutil.copytree(results, first_run)

    def deviate(config):
        config["design"]["falsifier"]["threshold"] = 0.05
        config["conditions"]["slow"]["lift_time"] = 1.4

    edit_config(work, deviate)
    proc = run_snakemake(work, "--forceall")
    assert "the design deviates from its registration" in proc.stderr
    assert (results / "registration.json").read_bytes() == registered  # never rewritten
    noted = json.loads((results / "deviations.json").read_text())["deviations_seen"]
    assert [c["key"] for c in noted[0]["changes"]] == [
        "design.falsifier.threshold",
        "conditions.slow.lift_time",
    ]
    manifest = json.loads((results / "manifest.json").read_text())["registration"]
    assert [c["key"] for c in manifest["deviations"]] == [
        "design.falsifier.threshold",
        "conditions.slow.lift_time",
    ]
    assert manifest["deviation_noted"]["results_existed"] is True
    assert manifest["deviation_noted"]["of_registered_design"] is True
    report = (results / "report.md").read_text()
    assert "before any rollout" not in report and "before the data" not in report
    assert "when results existed: a summary of the registered design" in report

    def check():
        return verify_results(
            results, config_path=work / "config" / "config.yaml", repo_root=work, resimulate=0
        )

    assert check().ok, check().format()
    good = (results / "registration.json").read_text()
    tampered = json.loads(good)
    tampered["current"]["design"]["sections"]["design"]["falsifier"]["threshold"] = 0.05
    (results / "registration.json").write_text(json.dumps(tampered))
    verdict = check()[f"{RESULTS}/registration.json"]
    assert verdict.status is Status.TAMPERED
    assert "its design is not the one its sha256 was taken of" in "; ".join(verdict.reasons)
    (results / "registration.json").write_text(good)

    # issue 42 item 5: registered again after the results, and rebuilt: the report said
    # "registered ... before any rollout"; the record keeps what results existed, for ever
    seen = provenance.file_sha256(results / "analysis" / "summary.json")
    monkeypatch.chdir(work)
    assert cli.main(["register", "--again", "--reason", "threshold from the pilot"]) == 0
    data = json.loads((results / "registration.json").read_text())
    assert data["earlier"][0]["design_sha256"] == json.loads(registered)["current"]["design_sha256"]
    run_snakemake(work)
    manifest = json.loads((results / "manifest.json").read_text())["registration"]
    assert manifest["deviations"] == [] and not manifest["before_any_rollout"]
    assert len(manifest["earlier"]) == 1
    witnessed = manifest["results_when_registered"]
    assert witnessed["existed"] and witnessed["sha256"]["analysis/summary.json"] == seen
    report = (results / "report.md").read_text()
    assert "before any rollout" not in report
    assert "after results existed" in report and f"sha256 `{seen[:12]}`" in report
    assert check().ok

    text = render(diff_runs(first_run, results))
    assert text.index("Registration") < text.index("How they were made")
    assert "REGISTERED DESIGN CHANGED" in text
    assert "design.falsifier.threshold: 0.0 -> 0.05" in text

    # issue 42 item 8: the registration edited and every hash taken again: the outputs made
    # before it record another registration; Snakemake refuses to start, verify names it
    good = (results / "registration.json").read_bytes()
    forged = registration.read(results / "registration.json")
    forged["current"]["design"]["sections"]["analysis"]["confidence"] = 0.9
    forged["current"]["design_sha256"] = registration.sha256_of(forged["current"]["design"])
    forged["current"]["sha256"] = registration.entry_sha256(forged["current"])
    registration._write(forged, results / "registration.json", repo_root=work)
    assert registration.problems(registration.read(results / "registration.json")) == []
    proc = run_snakemake(work, check=False)
    assert proc.returncode != 0
    assert "the registration was rewritten after it; no job was started" in proc.stderr
    verdict = check()[f"{RESULTS}/registration.json"]
    assert verdict.status is Status.TAMPERED
    assert "which the record does not hold" in "; ".join(verdict.reasons)
    (results / "registration.json").write_bytes(good)

    # issue 42 item 6: the registration deleted, the design changed, --forceall: registered
    # anew "before any rollout"; the results in the folder were there to see
    (results / "registration.json").unlink()
    edit_config(work, lambda c: c["design"]["falsifier"].update(threshold=0.1))
    run_snakemake(work, "--forceall")
    data = registration.read(results / "registration.json")
    assert data["earlier"] == []  # what was deleted is gone ...
    witnessed = data["current"]["results_when_registered"]
    assert witnessed["existed"] and witnessed["files"] > 0 and witnessed["records"] > 0
    manifest = json.loads((results / "manifest.json").read_text())["registration"]
    assert manifest["before_any_rollout"] is False  # ... and the new one says when it came
    report = (results / "report.md").read_text()
    assert "before any rollout" not in report and "after results existed" in report


def test_plan_of_a_registered_design_reads_the_pilot(tmp_path, config, capsys):
    layout = Layout(tmp_path / "results" / "x")
    registration.register(config, layout=layout, repo_root=REPO_ROOT)
    assert cli.main(["plan", str(layout.root)]) == 0
    out = capsys.readouterr().out
    assert "| pairs (N) | 200 |" in out
    assert "assumed: half the pairs discordant" in out
    # a pilot: 40 pairs, 10 discordant
    import pyarrow as pa
    import pyarrow.parquet as pq

    for name, column in (("slow", [True] * 30 + [False] * 10), ("fast", [True] * 40)):
        path = layout.development.rollout_table(name)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table({"success": column}), path)
    assert cli.main(["plan", str(layout.root), "--effect", "0.1"]) == 0
    out = capsys.readouterr().out
    assert "0.250 (the pilot: 40 pairs" in out
    assert "pairs for a difference of +0.100" in out
    assert "no results yet: `mjtrial register --again --reason TEXT` records this one)" in out
    # Issue 42 item 15: once results exist, registering a new plan would be a design made
    # after the data; the plan is said to be post hoc instead
    shard = layout.rollouts_dir() / "slow" / "shard-00000.parquet"
    shard.parent.mkdir(parents=True)
    pq.write_table(pa.table({"success": [True]}), shard)
    assert cli.main(["plan", str(layout.root), "--effect", "0.1"]) == 0
    out = capsys.readouterr().out
    assert "register --again" not in out
    assert f"results exist ({layout.rollouts_dir()}), so this plan comes after them" in out


def test_a_deleted_record_of_deviations_is_named_with_how_to_restore_it(built, tmp_path):
    """Issue 42 item 15: `deviations.json` is no rule's output, so deleting it was "Nothing to
    be done", and verify called the manifest (which records the deviation noted) tampered
    without saying why. Now the workflow's load and verify name the file, what it held and
    how to restore it, and the command given does."""
    work = tmp_path / "copy"
    shutil.copytree(built, work, symlinks=True)
    results = work / RESULTS

    def threshold(config):
        config["design"]["falsifier"]["threshold"] = 0.01

    edit_config(work, threshold)
    run_snakemake(work)
    noted = json.loads((results / "manifest.json").read_text())["registration"]
    first_run = noted["deviation_noted"]["first_run_utc"]

    def check():
        return verify_results(
            results, config_path=work / "config" / "config.yaml", repo_root=work, resimulate=0
        )

    assert check().ok, check().format()
    (results / "deviations.json").unlink()
    lost = (
        f"missing: {RESULTS}/manifest.json records the changed design's first run at "
        f"{first_run} (registration.deviation_noted), a fact of that moment that no job can "
        "rebuild; put the file back from a copy of the results folder, or `snakemake -c2 -R "
    )
    report = check()
    verdict = report[f"{RESULTS}/deviations.json"]
    assert verdict.status is Status.MISSING, report.format()
    [reason] = verdict.reasons
    assert reason.startswith(lost), reason
    assert reason.endswith(
        f"-R {RESULTS}/manifest.json` notes the deviation anew, as first run then"
    )
    # the workflow's load names it (on any start: here the one the reason gives) ...
    restored = run_snakemake(work, "-R", f"{RESULTS}/manifest.json")
    line = f"mjtrial: {RESULTS}/deviations.json: {lost}"
    assert any(x.startswith(line) for x in restored.stderr.splitlines()), restored.stderr
    assert check().ok, check().format()  # ... and that command restores it


def test_a_policy_file_swapped_after_registration_is_a_deviation(tmp_path):
    """Issue 42 item 7: the registration hashed the task and the model, not the policy graph and
    contract a condition runs, so a policy swapped after the data was no deviation."""
    work = copy_workflow(tmp_path)
    config = yaml.safe_load((work / "config" / "cartpole_latency.yaml").read_text())
    name = next(iter(config["conditions"]))
    config["conditions"][name]["policy"] = "policies/cartpole_bc/seed-1.onnx"
    registered = registration.design_record(config, repo_root=work)
    files = registered["policy_files_sha256"]
    assert set(files) == {"policies/cartpole_bc/seed-1.onnx", "policies/cartpole_bc/policy.yaml"}
    graph = work / "policies" / "cartpole_bc" / "seed-1.onnx"
    assert (
        files["policies/cartpole_bc/seed-1.onnx"] == hashlib.sha256(graph.read_bytes()).hexdigest()
    )
    data = {"current": {"design": registered}}
    shutil.copy(work / "policies" / "cartpole_bc" / "seed-2.onnx", graph)  # swapped
    contract = work / "policies" / "cartpole_bc" / "policy.yaml"
    contract.write_text(contract.read_text() + "\n# edited\n")
    found = registration.deviations(data, registration.design_record(config, repo_root=work))
    assert [c["key"] for c in found] == [
        "policy_files_sha256.policies/cartpole_bc/policy.yaml",
        "policy_files_sha256.policies/cartpole_bc/seed-1.onnx",
    ]
    # a design without a policy file is registered as before (no key of its own)
    plain = yaml.safe_load((work / "config" / "config.yaml").read_text())
    assert "policy_files_sha256" not in registration.design_record(plain, repo_root=work)


def test_the_results_a_registration_witnesses(tmp_path, config):
    """Issue 42 item 6: results in the folder, or only in Snakemake's records of them (the
    folder deleted), make a registration one made after results existed; the states, the
    pilot's development folder and the logs do not."""
    layout = Layout(Path("results") / "x")
    (tmp_path / layout.root / "development").mkdir(parents=True)
    (tmp_path / layout.development.states).write_bytes(b"pilot")
    (tmp_path / layout.states).write_bytes(b"states")
    (tmp_path / layout.log("states")).parent.mkdir()
    (tmp_path / layout.log("states")).write_text("log")
    assert registration.results_witness(layout, workdir=tmp_path) == {
        "existed": False,
        "files": 0,
        "records": 0,
        "sha256": {},
    }
    # Snakemake's record of a rollout table whose file is gone
    metadata = tmp_path / ".snakemake" / "metadata"
    metadata.mkdir(parents=True)
    table = (layout.root / "rollouts" / "fast.parquet").as_posix()
    (metadata / base64.urlsafe_b64encode(table.encode()).decode()).write_text("{}")
    seen = registration.results_witness(layout, workdir=tmp_path)
    assert (seen["existed"], seen["files"], seen["records"]) == (True, 0, 1)
    # a summary in the folder, with its sha256
    (tmp_path / layout.summary).parent.mkdir(parents=True)
    (tmp_path / layout.summary).write_text('{"falsifier": {}}')
    seen = registration.results_witness(layout, workdir=tmp_path)
    assert seen["files"] == 1
    assert seen["sha256"] == {
        "analysis/summary.json": hashlib.sha256(b'{"falsifier": {}}').hexdigest()
    }


def test_stamps_disagree_with_a_registration_rewritten_after_them(tmp_path, config):
    """Issue 42 item 8: the registration's sha256 in every stamp made after it; a record
    rewritten and rehashed later is not the one they record."""
    layout = Layout(tmp_path / "results" / "x")
    data = registration.register(config, layout=layout, repo_root=REPO_ROOT)
    current = data["current"]
    assert current["sha256"] == registration.entry_sha256(current)
    made = {"rule": "rollout:fast#00000", "registration_sha256": current["sha256"]}
    later = {**made, "created_utc": current["registered_utc"]}
    assert registration.stamp_problems(data, {"a.parquet": later, "states": {"rule": "s"}}) == []
    # made before the registration it records: impossible for an honest run
    early = {**made, "created_utc": "2000-01-01T00:00:00Z"}
    (line,) = registration.stamp_problems(data, {"a.parquet": early})
    assert "a.parquet was made on 2000-01-01T00:00:00Z under registration" in line
    # the design edited and every hash taken again
    forged = copy.deepcopy(data)
    forged["current"]["design"]["sections"]["design"]["falsifier"]["threshold"] = 0.05
    forged["current"]["design_sha256"] = registration.sha256_of(forged["current"]["design"])
    forged["current"]["sha256"] = registration.entry_sha256(forged["current"])
    forged["sha256"] = registration.sha256_of(registration._sealed_part(forged))
    assert registration.problems(forged) == []  # consistent in itself
    (line,) = registration.stamp_problems(forged, {"a.parquet": later})
    assert line == (
        f"a.parquet was made under registration {current['sha256'][:12]}, which the record does "
        "not hold: the registration was rewritten after it"
    )
    # re-registered: what was made under the earlier one is in the record
    again = registration.register(config, layout=layout, repo_root=REPO_ROOT, again=True)
    assert registration.stamp_problems(again, {"a.parquet": later}) == []


def test_the_plan_says_a_pilot_ran_when_it_had_no_discordant_pair(tmp_path, config):
    """Issue 42 item 9: a pilot whose pairs all agreed gave the plan "no pilot"."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    layout = Layout(tmp_path / "results" / "x")
    for name in ("slow", "fast"):
        path = layout.development.rollout_table(name)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table({"success": [True] * 4}), path)
    plan = registration.registered_plan(config, layout=layout)
    assert "no pilot" not in plan["source"]
    assert "the pilot's 4 pairs" in plan["source"] and "had none discordant" in plan["source"]


def _swap_seeds(config):
    states = config["states"]
    states["seed"], states["development_seed"] = states["development_seed"], states["seed"]


@pytest.fixture(scope="module")
def piloted_then_run(tmp_path_factory):
    """The guide's way in: a dry run, a cheap pilot (`--config 'pilot={n: 4}'`), a run the
    states job refuses (the seeds swapped: the evaluation states would be the pilot's), then
    the clean run. Whether a registration existed after each step."""
    work = copy_workflow(tmp_path_factory.mktemp("piloted"))

    def small(config):
        config["states"]["n"] = 12
        config["rollout"]["shard_size"] = 5
        config["analysis"]["n_resamples"] = 200
        config["recording"]["episodes"] = "none"

    edit_config(work, small)
    registered = work / RESULTS / "registration.json"
    seen = {}
    run_snakemake(work, "-n")
    run_snakemake(work, "-n", "pilot")
    seen["dry run"] = registered.exists()
    run_snakemake(work, "pilot", "--config", "pilot={n: 4}")
    seen["pilot"] = registered.exists()
    edit_config(work, _swap_seeds)
    refused = run_snakemake(work, check=False)
    seen["refused by the states job"] = registered.exists()
    edit_config(work, _swap_seeds)
    assert refused.returncode != 0 and "the pilot" in refused.stderr, refused.stderr
    run_snakemake(work)
    return work, seen


def test_the_design_is_registered_when_the_first_rollout_starts(piloted_then_run):
    """Issue 42 item 9: a dry run, a pilot and a run the states job refused each wrote the
    registration (a drafted config frozen as the design; the plan then said "no pilot")."""
    work, seen = piloted_then_run
    assert seen == {"dry run": False, "pilot": False, "refused by the states job": False}
    results = work / RESULTS
    data = registration.read(results / "registration.json")
    current = data["current"]
    # the plan reads the pilot that ran before it
    assert "no pilot" not in current["plan"]["source"]
    assert "pilot" in current["plan"]["source"] and "4 pairs" in current["plan"]["source"]
    assert current["results_when_registered"]["existed"] is False
    # after the states job, before every rollout; every stamp after it records it
    manifest = json.loads((results / "manifest.json").read_text())
    stamps = manifest["stamps"]
    states = stamps[f"{RESULTS}/states.parquet"]
    rollouts = [s for s in stamps.values() if s["rule"].startswith("rollout:")]
    assert states["created_utc"] <= current["registered_utc"]
    assert rollouts and all(current["registered_utc"] <= s["created_utc"] for s in rollouts)
    assert manifest["registration"]["before_any_rollout"] is True
    assert "registration_sha256" not in states  # made before it
    carried = {p: s.get("registration_sha256") for p, s in stamps.items() if p != states}
    carried = {p: sha for p, sha in carried.items() if not p.endswith("states.parquet")}
    assert set(carried.values()) == {current["sha256"]}, carried
    assert "Registered on" in (results / "report.md").read_text()
    assert "before any rollout" in (results / "report.md").read_text()


def test_a_clean_run_after_a_cheap_pilot_verifies(piloted_then_run):
    """Issue 42 item 10: after `--config 'pilot={n: 4}'`, verify re-simulated the pilot as if
    it had run all 12 development states: "no row for states [...]", NOT verified."""
    work, _ = piloted_then_run
    report = verify_results(
        work / RESULTS, config_path=work / "config" / "config.yaml", repo_root=work, resimulate=2
    )
    assert report.ok, report.format()
    development = Layout.of("research_mode").development
    assert report.status_of(development.shard_table("fast", "00000").as_posix()) is Status.OK
