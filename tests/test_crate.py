"""The run's RO-Crate (`results/<experiment>/ro-crate-metadata.json`): what it lists, checked
against the files, the seal, the stamps and Snakemake's own records read here directly; the
validator at REQUIRED severity, offline; `runcrate report`; `mjtrial provenance` for every file
under results; `mjtrial verify` on an edited or missing crate."""

from __future__ import annotations

import base64
import hashlib
import json
import re
import shutil
import socket
import subprocess
import sys
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from mjtrial import cli, provenance
from mjtrial.crate import validation
from mjtrial.files.layout import Layout
from mjtrial.verify import Status, verify_results

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")
RUNCRATE = str(Path(sys.executable).parent / "runcrate")


def graph(crate: Path) -> dict[str, dict]:
    """The crate's entities by @id, read as plain JSON."""
    return {e["@id"]: e for e in json.loads(crate.read_text())["@graph"]}


def refs(value) -> list[str]:
    """The @ids a property refers to (one reference or a list of them)."""
    values = value if isinstance(value, list) else [value]
    return [v["@id"] for v in values if isinstance(v, dict) and "@id" in v]


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def crate_id(path: str) -> str:
    """A sealed output's id in the folder's crate: its path in the results folder."""
    return path.removeprefix(f"{LAYOUT.root.as_posix()}/")


def flattened(value, prefix=""):
    """A config slice as the crate's PropertyValues hold it: dotted keys; lists and null as
    JSON text."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from flattened(v, f"{prefix}.{k}" if prefix else k)
    elif isinstance(value, (bool, int, float, str)):
        yield prefix, value
    else:
        yield prefix, json.dumps(value, sort_keys=True)


def snakemake_records(workdir: Path) -> dict[str, dict]:
    """Snakemake's metadata records by output path (the file names are the paths in urlsafe
    base64, long ones split into folders whose names begin with '@')."""
    folder = workdir / ".snakemake" / "metadata"
    records = {}
    for f in folder.rglob("*"):
        if f.is_file():
            encoded = "".join(p.removeprefix("@") for p in f.relative_to(folder).parts)
            records[base64.urlsafe_b64decode(encoded).decode()] = json.loads(f.read_text())
    return records


@pytest.fixture(scope="module")
def sealed(built) -> dict[str, str]:
    return json.loads((built / LAYOUT.seal).read_text())["outputs"]


@pytest.fixture(scope="module")
def entities(built) -> dict[str, dict]:
    return graph(built / LAYOUT.crate)


def test_every_sealed_file_is_listed_with_the_seals_sha256_and_its_size(built, sealed, entities):
    for path, sha in sealed.items():
        file = built / path
        if file.is_dir():  # a shard's recordings: one Dataset, its files not listed one by one
            entity = entities[crate_id(path) + "/"]
            assert entity["@type"] == "Dataset" and entity["sha256"] == sha
            assert not [i for i in entities if i.startswith(crate_id(path) + "/") and i[-1] != "/"]
        else:
            entity = entities[crate_id(path)]
            assert entity["@type"] == "File"
            assert entity["sha256"] == sha == sha256(file)
            assert int(entity["contentSize"]) == file.stat().st_size
    seal = entities["seal.json"]
    assert seal["sha256"] == sha256(built / LAYOUT.seal)
    for file in (built / LAYOUT.source).rglob("*"):
        if file.is_file() and not file.name.startswith("."):
            entity = entities["source/" + file.relative_to(built / LAYOUT.source).as_posix()]
            assert entity["sha256"] == sha256(file)
            assert int(entity["contentSize"]) == file.stat().st_size
    # Every data entity of the crate is there.
    listed = {i for i, e in entities.items() if e.get("@type") in ("File", "Dataset")}
    assert all((built / LAYOUT.root / i).exists() for i in listed if i != "./")


def test_the_copy_of_the_sources_is_the_workflow_and_the_code_that_ran(built, entities):
    root = entities["./"]
    assert refs(root["mainEntity"]) == ["source/Snakefile"]
    workflow = entities["source/Snakefile"]
    assert set(workflow["@type"]) == {
        "File",
        "SoftwareSourceCode",
        "ComputationalWorkflow",
        "HowTo",
    }
    language = entities[refs(workflow["programmingLanguage"])[0]]
    assert language["name"] == "Snakemake" and language["version"] == "9.27.1"
    assert (built / LAYOUT.source / "Snakefile").read_bytes() == (built / "Snakefile").read_bytes()
    for script in (built / "workflow" / "scripts").glob("*.py"):
        copy = built / LAYOUT.source / "workflow" / "scripts" / script.name
        assert copy.read_bytes() == script.read_bytes()
    # The package that ran: what the stamps record of each module.
    code = provenance.read_stamp(built / LAYOUT.summary)["extra"]["code"]
    stats = built / LAYOUT.source / "src" / "mjtrial" / "stats" / "paired.py"
    assert sha256(stats) == code["mjtrial.stats.paired"]
    # No git checkout in the test copy: the version names the copy's own digest.
    assert workflow["version"].startswith("sha256:" + provenance.file_sha256(built / LAYOUT.source))


def test_each_job_is_an_action_with_its_inputs_config_outputs_and_times(built, sealed, entities):
    jobs: dict[str, list[str]] = {}
    for path in [*sealed, LAYOUT.seal.as_posix()]:
        jobs.setdefault(provenance.read_stamp(built / path)["rule"], []).append(path)
    # 3 shards of each condition, and one job of each other stage
    assert len([r for r in jobs if r.startswith("rollout:")]) == 6
    actions = {e["name"]: e for i, e in entities.items() if i.startswith("#job/")}
    assert set(actions) == {*jobs, "crate"}
    records = snakemake_records(built)
    workflow = entities["source/Snakefile"]
    for rule, outputs in jobs.items():
        action = actions[rule]
        folders = {p for p in outputs if (built / p).is_dir()}
        assert sorted(refs(action["result"])) == sorted(
            crate_id(p) + ("/" if p in folders else "") for p in outputs
        )
        stamp = provenance.read_stamp(built / outputs[0])
        objects = refs(action["object"])
        for record in stamp["inputs"].values():
            for r in record if isinstance(record, list) else [record]:
                p = r["path"]
                want = crate_id(p) if p.startswith(LAYOUT.root.as_posix()) else "source/" + p
                assert want in objects or want + "/" in objects, (rule, p)
        values = {(entities[o]["name"], entities[o]["value"]) for o in objects if o[0] == "#"}
        assert values == set(flattened(stamp["config_slice"])) | {
            (f"seed.{k}", v) for k, v in stamp["seeds"].items()
        }
        tool = entities[refs(action["instrument"])[0]]
        assert refs(action["instrument"])[0] in refs(workflow["hasPart"])
        assert tool["version"] == f"sha256:{stamp['extra']['code_sha256']}"
        # Start and end: Snakemake's records of the outputs, and the stamps made in between.
        start = min(records[p]["starttime"] for p in outputs)
        end = max(records[p]["endtime"] for p in outputs)
        assert datetime.fromisoformat(action["startTime"]).timestamp() == pytest.approx(
            start, abs=1e-3
        )
        assert datetime.fromisoformat(action["endTime"]).timestamp() == pytest.approx(end, abs=1e-3)
        made = datetime.fromisoformat(stamp["created_utc"].replace("Z", "+00:00")).timestamp()
        assert int(start) <= made <= end + 1
        control = entities["#control/" + action["@id"].removeprefix("#job/")]
        assert refs(control["object"]) == [action["@id"]]
        step = entities[refs(control["instrument"])[0]]
        assert refs(step["workExample"]) == refs(action["instrument"])
    organize = entities["#snakemake-run"]
    controls = sorted(i for i in entities if i.startswith("#control/"))
    assert sorted(refs(organize["object"])) == controls
    assert refs(organize["result"]) == ["#run"]
    run = entities["#run"]
    assert refs(run["instrument"]) == ["source/Snakefile"]
    assert sorted(refs(run["result"])) == sorted(
        crate_id(p) + ("/" if (built / p).is_dir() else "")
        for p in [*sealed, LAYOUT.seal.as_posix()]
    )


def test_the_crate_carries_its_stamp_and_the_libraries(built, entities):
    stamp = json.loads(entities["#mjtrial-provenance"]["value"])
    assert stamp["rule"] == "crate"
    assert stamp["inputs"]["seals"] == [
        {"path": LAYOUT.seal.as_posix(), "sha256": sha256(built / LAYOUT.seal)}
    ]
    assert provenance.read_stamp(built / LAYOUT.crate) == stamp
    for key, version in stamp["versions"].items():
        apps = [e for e in entities.values() if e.get("version") == version]
        assert any(e["@type"] == "SoftwareApplication" for e in apps), key
    assert entities["https://pypi.org/project/mujoco/3.14.0/"]["name"] == "MuJoCo"
    assert json.loads((built / LAYOUT.crate).read_text())["@context"] == [
        "https://w3id.org/ro/crate/1.1/context",
        "https://w3id.org/ro/terms/workflow-run/context",  # where sha256 is defined
    ]


def test_every_file_under_results_answers_mjtrial_provenance(built, entities, capsys):
    """Including each shard's blueprint.rbl (its folder's stamp) and Snakemake's timestamps."""
    crate_stamp = json.loads(entities["#mjtrial-provenance"]["value"])
    root = built / LAYOUT.root
    files = [p for p in root.rglob("*") if p.is_file()]
    assert any(p.name == "blueprint.rbl" for p in files)
    for file in files:
        assert cli.main(["provenance", str(file)]) == 0, file
        stamp = json.loads(capsys.readouterr().out)
        rel = file.relative_to(root)
        if rel.parts[0] == "source" or file == built / LAYOUT.crate:
            assert stamp == crate_stamp, file
        elif file.parent.name.startswith("shard-") and file.suffix != ".rrd":
            folder = json.loads((file.parent / "recordings.json").read_text())["provenance"]
            assert stamp == folder, file
        elif file.suffix == ".log":
            first = file.read_text().splitlines()[0]
            assert stamp == json.loads(first.split(": ", 1)[1]), file


def test_the_validator_finds_no_required_issue_offline(built, tmp_path, monkeypatch):
    def no_network(*args, **kwargs):
        raise AssertionError("the validator opened a connection")

    monkeypatch.setattr(socket.socket, "connect", no_network)
    findings = validation.validate(built / LAYOUT.root, cache_path=tmp_path / "cache" / "http")
    assert findings == [], "\n".join(f.line() for f in findings)


def test_the_validator_sees_a_broken_crate(built, tmp_path):
    """The check above can fail: the same validator on a copy missing what the profiles
    require (the workflow's steps' HowTo type, the engine run's step executions)."""
    folder = tmp_path / "results"
    shutil.copytree(built / LAYOUT.root, folder, ignore=shutil.ignore_patterns("*.rrd"))
    document = json.loads((folder / "ro-crate-metadata.json").read_text())
    for entity in document["@graph"]:
        if entity["@id"] == "source/Snakefile":
            entity["@type"].remove("HowTo")
        if entity["@id"] == "#snakemake-run":
            del entity["object"]
    (folder / "ro-crate-metadata.json").write_text(json.dumps(document))
    findings = validation.validate(folder, cache_path=tmp_path / "cache" / "http")
    checks = {f.check for f in findings}
    assert {"ComputationalWorkflow with steps type", "OrganizeAction object"} <= checks
    assert {f.severity for f in findings} == {"REQUIRED"}


def test_the_vendored_contexts_serve_the_validator_offline_and_nothing_else(tmp_path):
    from rocrate_validator.utils.http import HttpRequester

    documents = validation.context_documents()
    records = json.loads((validation.CONTEXTS_DIR / "contexts.json").read_text())
    for record in records:
        data = (validation.CONTEXTS_DIR / record["file"]).read_bytes()
        assert hashlib.sha256(data).hexdigest() == record["sha256"]
        assert json.loads(data)["@context"]  # a JSON-LD context document
    assert (
        "sha256"
        in json.loads(documents["https://w3id.org/ro/terms/workflow-run/context"])["@context"]
    )
    validation.seed_cache(tmp_path / "http")
    requester = HttpRequester()
    for url, data in documents.items():
        response = requester.get(url, headers={"Accept": "application/ld+json"})
        assert response.status_code == 200 and response.content == data
    missing = requester.get("https://w3id.org/ro/crate/1.2/context")
    assert missing.status_code == 504  # offline: a URL it was not given is a cache miss


def test_runcrate_report_reads_the_crate(built, sealed):
    proc = subprocess.run(
        [RUNCRATE, "report", str(built / LAYOUT.root)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    actions = [line.split()[1] for line in proc.stdout.splitlines() if line.startswith("action:")]
    rules = {provenance.read_stamp(built / p)["rule"] for p in [*sealed, LAYOUT.seal.as_posix()]}
    assert actions[0] == "#run"  # the workflow's run first
    assert len(actions) == 1 + len(rules) + 1  # and every job, the crate's own included
    assert "  step: #step/rollout" in proc.stdout
    assert "    states.parquet" in proc.stdout


@pytest.fixture
def work(built, tmp_path) -> Path:
    workdir = tmp_path / "experiment"
    shutil.copytree(built, workdir, symlinks=True)
    return workdir


def verify(workdir: Path):
    return verify_results(
        workdir / LAYOUT.root,
        config_path=workdir / "config" / "config.yaml",
        repo_root=workdir,
        resimulate=0,
    )


CRATE = LAYOUT.crate.as_posix()
SOURCE = LAYOUT.source.as_posix()


def test_verify_checks_the_crate_and_its_copy(work):
    report = verify(work)
    assert report.ok, report.format()
    assert report[CRATE].status is Status.OK and report[SOURCE].status is Status.OK


def test_an_edited_crate_is_tampered(work):
    crate = work / LAYOUT.crate
    document = json.loads(crate.read_text())
    for entity in document["@graph"]:
        if entity["@id"] == "states.parquet":
            entity["contentSize"] = str(int(entity["contentSize"]) + 1)
    crate.write_text(json.dumps(document, indent=2))
    report = verify(work)
    assert report[CRATE].status is Status.TAMPERED
    assert "states.parquet: contentSize" in report[CRATE].reasons[0]
    assert [o.path for o in report.outputs if o.status is not Status.OK] == [CRATE]


def test_a_crate_whose_times_cannot_hold_its_stamps_is_tampered(work):
    crate = work / LAYOUT.crate
    document = json.loads(crate.read_text())
    for entity in document["@graph"]:
        if entity["@id"] == "#job/analysis":
            entity["startTime"] = "2099-01-01T00:00:00.000+00:00"
    crate.write_text(json.dumps(document, indent=2))
    report = verify(work)
    assert report[CRATE].status is Status.TAMPERED
    assert "analysis starts at 2099-01-01" in report[CRATE].reasons[0]


def test_an_output_forged_after_its_job_ended_is_seen_by_the_crates_times(work):
    """A shard table rewritten under a fresh stamp, everything after it rebuilt by Snakemake:
    the stamps and seals agree again, but the stamp was made after the job that Snakemake
    records ran."""
    import pyarrow.parquet as pq
    from conftest import run_snakemake

    shard = work / LAYOUT.shard_table("slow", "00001")
    time.sleep(1.1)  # stamps have a resolution of one second
    made = datetime.now(timezone.utc) + timedelta(seconds=120)  # beyond the crate's slack
    stamp = dict(provenance.read_stamp(shard), created_utc=made.strftime("%Y-%m-%dT%H:%M:%SZ"))
    provenance.write_parquet(pq.read_table(shard).replace_schema_metadata(None), shard, stamp)
    run_snakemake(work)
    report = verify(work)
    assert [o.path for o in report.outputs if o.status is not Status.OK] == [CRATE]
    assert "rollout:slow#00001 ends at" in report[CRATE].reasons[0]


def test_a_missing_crate_is_missing(work):
    (work / LAYOUT.crate).unlink()
    report = verify(work)
    assert report[CRATE].status is Status.MISSING
    assert report[SOURCE].status is Status.TAMPERED  # its stamp is the crate's
    assert not report.ok


def test_an_edited_copy_of_the_sources_is_tampered(work):
    stats = work / LAYOUT.source / "src" / "mjtrial" / "stats" / "paired.py"
    stats.write_text(stats.read_text() + "\n# an edit\n")
    report = verify(work)
    assert report[SOURCE].status is Status.TAMPERED
    assert "source/src/mjtrial/stats/paired.py: its sha256 differs" in report[SOURCE].reasons[0]
    assert "is not the code analysis ran" in report[SOURCE].reasons[0]
    assert report[CRATE].status is Status.OK  # the edit is the copy's


def test_an_edited_output_is_named_and_the_crate_is_stale_through_its_seal(work):
    report_md = work / LAYOUT.report
    report_md.write_text(report_md.read_text() + "\nforged\n")
    report = verify(work)
    assert report[LAYOUT.report.as_posix()].status is Status.TAMPERED
    assert report[CRATE].reasons == ("input stale: seal.json",)
    assert report[CRATE].status is Status.STALE


def test_snakemake_rebuilds_a_deleted_crate_and_verify_is_ok_again(work):
    from conftest import run_snakemake

    (work / LAYOUT.crate).unlink()
    proc = run_snakemake(work)
    assert "rule crate:" in proc.stdout + proc.stderr
    assert verify(work).ok
    proc = run_snakemake(work, "-n")
    assert "Nothing to be done" in proc.stdout + proc.stderr


def test_the_license_the_config_gives_is_linked_and_none_is_said(built, entities):
    from mjtrial.crate.check import covered_seals, recorded_times
    from mjtrial.crate.graph import crate_metadata
    from mjtrial.crate.record import read_record

    assert entities["./"]["license"].startswith("No license chosen")  # the built-in config
    stamp = json.loads(entities["#mjtrial-provenance"]["value"])
    for given, identifier in [
        ("CC-BY-4.0", "https://spdx.org/licenses/CC-BY-4.0"),
        ("https://example.org/terms", "https://example.org/terms"),
    ]:
        licensed = {**stamp, "config_slice": {"license": given}}
        record = read_record(
            LAYOUT.__class__(built / LAYOUT.root),
            repo_root=built,
            seals=[built / p for p in covered_seals(stamp)],
            crate_stamp=licensed,
            times=recorded_times(entities),
        )
        graph_ = {e["@id"]: e for e in crate_metadata(record)["@graph"]}
        assert graph_["./"]["license"] == {"@id": identifier}
        assert graph_[identifier]["name"] == given


def test_every_file_the_jobs_read_travels_in_the_copy_of_the_sources(built):
    """The model and the task the stamps record are in the copy, as they were read."""
    from mjtrial.crate.record import read_inputs, sealed_stamps

    read = read_inputs(sealed_stamps([built / LAYOUT.seal], repo_root=built))
    assert {"models/gantry_gripper/scene.xml", "tasks/gantry_lift/task.py"} <= set(read)
    for path in read:
        if not path.startswith(f"{LAYOUT.root.as_posix()}/"):
            assert sha256(built / LAYOUT.source / path) == sha256(built / path), path


def test_a_model_or_task_outside_the_usual_folders_is_copied_and_nothing_outside(tmp_path):
    """A lab keeps its model and task in its own folder: the copy holds them; a path that
    leaves the working folder is never followed."""
    from mjtrial.crate.sources import source_files

    (tmp_path / "lab" / "arm").mkdir(parents=True)
    (tmp_path / "lab" / "arm" / "arm.xml").write_text("<mujoco/>")
    (tmp_path / "secret.txt").write_text("not a source")
    read = ["lab/arm/arm.xml", "../secret.txt", str(tmp_path / "secret.txt"), "lab/missing.py"]
    files = source_files(tmp_path / "lab" / "..", read)
    assert files["lab/arm/arm.xml"] == tmp_path / "lab" / ".." / "lab/arm/arm.xml"
    assert not [k for k in files if "secret" in k or "missing" in k]


# A task folder whose name has a space and a non-ASCII letter; its ids in a crate, encoded
# once by hand: " " is %20 and "ü" (UTF-8 C3 BC) is %C3%BC.
ODD_FOLDER = "tasks/odd ü"
ODD_ID = "tasks/odd%20%C3%BC"
ODD = Layout.of("odd")


@pytest.fixture(scope="module")
def odd_names(built, tmp_path_factory) -> Path:
    """A copy of the built experiment with a second one whose task (`mjtrial new-task`'s)
    lives in `tasks/odd ü/`, built small; then the first experiment's crate rebuilt (its copy
    of the sources holds only the task and model folders its own jobs read)."""
    import yaml
    from conftest import run_snakemake

    work = tmp_path_factory.mktemp("names") / "experiment"
    shutil.copytree(built, work, symlinks=True)
    assert cli.main(["new-task", "odd", "--repo-root", str(work)]) == 0
    (work / "tasks" / "odd").rename(work / ODD_FOLDER)
    path = work / "config" / "odd.yaml"
    config = yaml.safe_load(path.read_text())
    config.update(model=f"{ODD_FOLDER}/model.xml", task=f"{ODD_FOLDER}/task.py")
    config["states"]["n"] = 10
    config["rollout"]["shard_size"] = 10
    config["analysis"]["n_resamples"] = 200
    config["recording"]["episodes"] = "none"  # the names are the task folder's: time saved
    path.write_text(yaml.safe_dump(config, sort_keys=False, allow_unicode=True))
    run_snakemake(work, "--configfile", "config/odd.yaml")
    run_snakemake(work, "-R", "crate")
    return work


def test_a_task_folder_named_with_a_space_and_a_non_ascii_letter_verifies(odd_names):
    entities = graph(odd_names / ODD.crate)
    assert f"source/{ODD_ID}/task.py" in entities and f"source/{ODD_ID}/model.xml" in entities
    assert not [i for i in entities if "%25" in i or " " in i or "ü" in i]  # encoded once
    job = entities["#job/rollout:firm/shard-00000"]
    assert {"@id": f"source/{ODD_ID}/task.py"} in job["object"]
    report = _verify_odd(odd_names)
    assert report.ok, report.format()
    # The other experiment, whose crate was rebuilt: its copy of the sources holds the task
    # folders its jobs read, not the odd one, and it verifies.
    assert f"source/{ODD_ID}/task.py" not in graph(odd_names / LAYOUT.crate)
    assert not (odd_names / LAYOUT.root / "source" / ODD_FOLDER).exists()
    assert (odd_names / LAYOUT.root / "source" / "tasks" / "gantry_lift" / "task.py").is_file()
    report = verify(odd_names)
    assert report.ok, report.format()


def _verify_odd(root):
    """The odd-named experiment's results verified in the checkout `root`."""
    return verify_results(
        root / ODD.root, config_path=root / "config" / "odd.yaml", repo_root=root, resimulate=0
    )


def test_a_task_folder_named_with_a_space_and_a_non_ascii_letter_validates_and_zips(
    odd_names, tmp_path, capsys
):
    import zipfile

    from rocrate.rocrate import ROCrate

    results = odd_names / ODD.root
    args = ["crate", str(results), "--repo-root", str(odd_names)]
    assert cli.main([*args, "--validate"]) == 0, capsys.readouterr()
    assert "validator: 0 REQUIRED issues" in capsys.readouterr().out
    archive = tmp_path / "odd.zip"
    assert cli.main([*args, "--zip", str(archive)]) == 0, capsys.readouterr().err
    with zipfile.ZipFile(archive) as z:
        assert f"{ODD_FOLDER}/task.py" in z.namelist()
        z.extractall(tmp_path / "elsewhere")
    crate = ROCrate(archive)  # ro-crate-py finds the task by its id
    assert crate.get(f"{ODD_ID}/task.py").type == "File"
    there = tmp_path / "elsewhere"
    report = _verify_odd(there)
    assert report.ok, report.format()


AUTHORS = [
    {
        "name": "Ada Lovelace",
        "orcid": "https://orcid.org/0000-0002-1825-0097",
        "affiliation": "Analytical Engine Lab",
    },
    {"name": "Émilie du Châtelet"},
]


def test_a_hand_added_author_is_tampered_and_says_where_to_set_it(work, capsys):
    crate = work / LAYOUT.crate
    document = json.loads(crate.read_text())
    for entity in document["@graph"]:
        if entity["@id"] == "./":
            entity["author"] = {"@id": "#ada"}
    document["@graph"].append({"@id": "#ada", "@type": "Person", "name": "Ada Lovelace"})
    crate.write_text(json.dumps(document, indent=2))
    report = verify(work)
    assert report[CRATE].status is Status.TAMPERED
    assert [o.path for o in report.outputs if o.status is not Status.OK] == [CRATE]
    how = "provenance.authors and provenance.keywords in the config: set them there"
    assert how in report[CRATE].reasons[0]
    out = work / "run.zip"
    args = ["crate", str(work / LAYOUT.root), "--zip", str(out), "--repo-root", str(work)]
    assert cli.main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and how in err[0] and not out.exists(), err


def test_the_authors_and_keywords_the_config_gives_are_in_the_crate_and_rerun_it_alone(
    work, tmp_path
):
    from conftest import edit_config, run_snakemake

    before = {p: sha256(work / p) for p in [LAYOUT.manifest, LAYOUT.report, LAYOUT.seal]}

    def described(config):
        config["provenance"]["authors"] = AUTHORS
        config["provenance"]["keywords"] = ["MuJoCo", "grasping"]

    edit_config(work, described)
    proc = run_snakemake(work)
    out = proc.stdout + proc.stderr
    jobs = [m.group(2) for m in re.finditer(r"^(local)?rule (\w+):", out, re.MULTILINE)]
    assert jobs == ["crate", "all"], out  # its own job: no result reruns for an author
    assert {p: sha256(work / p) for p in before} == before
    entities = graph(work / LAYOUT.crate)
    root = entities["./"]
    assert root["author"] == [
        {"@id": "https://orcid.org/0000-0002-1825-0097"},
        {"@id": "#author/%C3%89milie%20du%20Ch%C3%A2telet"},
    ]
    assert entities["https://orcid.org/0000-0002-1825-0097"] == {
        "@id": "https://orcid.org/0000-0002-1825-0097",
        "@type": "Person",
        "name": "Ada Lovelace",
        "affiliation": "Analytical Engine Lab",
    }
    assert entities["#author/%C3%89milie%20du%20Ch%C3%A2telet"]["name"] == "Émilie du Châtelet"
    assert root["keywords"] == ["MuJoCo", "grasping"]
    report = verify(work)
    assert report.ok, report.format()
    findings = validation.validate(work / LAYOUT.root, cache_path=tmp_path / "cache" / "http")
    assert findings == [], "\n".join(f.line() for f in findings)
