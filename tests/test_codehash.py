"""A stage's code is its script plus the package modules it imports, found from the source.

Unit tests of the import reading on hand-written sources; the closure against what Python
itself imports; and, end to end on a copy of the repository with its own package source, that
`touch` reruns nothing while an edit to one module reruns exactly the stages that import it
(and what depends on their outputs), with `mjtrial verify` naming that module.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT
from test_pipeline import planned_jobs

from mjtrial.files import codehash
from mjtrial.files.layout import BENCHMARK_STAGES, PILOT_STAGES, STAGES
from mjtrial.stages.stamping import stage_code

pytestmark = pytest.mark.end_to_end


def test_imports_are_read_wherever_they_stand():
    source = """
import os
import mjtrial.stats
from mjtrial import REPO_ROOT
from mjtrial.files import layout
from mjtrial.stages.rollout import run_shard
import numpy as np

def later():
    from mjtrial.taxonomy import classify
    import mjtrial.recording as rec
"""
    assert codehash.imported_modules(source) == {
        "mjtrial.stats",
        "mjtrial.files.layout",
        "mjtrial",  # REPO_ROOT is a name in the package, not a module
        "mjtrial.stages.rollout",
        "mjtrial.taxonomy",
        "mjtrial.recording",
    }


def test_relative_imports_resolve_against_the_importing_module():
    source = "from . import stamping\nfrom ..simulate import load_model\nfrom .rollout import x\n"
    assert codehash.imported_modules(source, module="mjtrial.stages.failures") == {
        "mjtrial.stages.stamping",
        "mjtrial.simulate",
        "mjtrial.stages.rollout",
    }
    # In a package's __init__, "." is the package itself.
    assert codehash.imported_modules("from .rollout import x", module="mjtrial.stages") == {
        "mjtrial.stages.rollout"
    }


def test_unknown_module_is_an_error():
    with pytest.raises(ModuleNotFoundError, match="mjtrial.no_such_module"):
        codehash.module_closure({"mjtrial.no_such_module"})


# Run by a fresh interpreter: imports nothing of mjtrial, then, for each request, forks a child
# that imports the request's modules and reports its mjtrial modules. The third-party modules
# the stages import are imported first, once (the list from a child that imports every
# request): a child then imports only mjtrial's own modules, which no third-party one imports.
_IMPORTS_IN_CHILDREN = r"""
import importlib, json, os, sys, traceback

def imported_by(modules):
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(read)
        code = 1
        try:
            for m in modules:
                importlib.import_module(m)
            with os.fdopen(write, "w") as f:
                json.dump(list(sys.modules), f)
            code = 0
        except BaseException:
            traceback.print_exc()
        finally:
            sys.stderr.flush()
            os._exit(code)
    os.close(write)
    with os.fdopen(read) as f:
        data = f.read()
    _, status = os.waitpid(pid, 0)
    if status != 0:
        sys.exit(f"importing {modules} failed")
    return json.loads(data)

def mjtrial(names):
    return sorted(m for m in names if m.split(".")[0] == "mjtrial")

requests = json.loads(sys.stdin.read())
for name in imported_by(sorted({m for ms in requests.values() for m in ms})):
    if not name.startswith("mjtrial"):
        try:
            importlib.import_module(name)
        except Exception:
            pass  # importable only within its package's own import: left to the children
assert mjtrial(sys.modules) == [], mjtrial(sys.modules)
print(json.dumps({key: mjtrial(imported_by(ms)) for key, ms in requests.items()}))
"""


def _runtime_imports(requests: dict[str, list[str]]) -> dict[str, set[str]]:
    """For each request, the mjtrial modules a process holds after importing its modules,
    starting from none (each a child forked from an interpreter without one)."""
    out = subprocess.run(
        [sys.executable, "-c", _IMPORTS_IN_CHILDREN],
        input=json.dumps(requests),
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    ).stdout
    return {key: set(modules) for key, modules in json.loads(out).items()}


@pytest.fixture(scope="module")
def stage_runtime_imports() -> dict[str, set[str]]:
    """Each stage's mjtrial modules as Python imports them for its script's top-level imports."""
    return _runtime_imports(
        {
            stage: sorted(codehash.imported_modules((REPO_ROOT / spec.script_path).read_text()))
            for stage, spec in STAGES.items()
        }
    )


@pytest.mark.parametrize("stage", list(STAGES))
def test_closure_holds_everything_python_imports_for_the_stage(stage, stage_runtime_imports):
    code = stage_code(stage)
    script = STAGES[stage].script_path
    assert script in code
    # The closure may hold more (imports inside functions), never less.
    assert stage_runtime_imports[stage] <= set(code) - {script}


def test_digest_changes_with_any_file_and_names_it():
    code = stage_code("analysis")
    edited = {**code, "mjtrial.stats": "0" * 64}
    assert codehash.code_digest(edited) != codehash.code_digest(code)
    assert codehash.changed_code(code, edited) == ["mjtrial.stats"]
    assert codehash.changed_code(code, {**code, "mjtrial.extra": "1"}) == ["mjtrial.extra"]


# --------------------------------------------------------------------------------------------
# End to end: a copy of the repository whose package is the copy's own source
# --------------------------------------------------------------------------------------------

# Rules whose inputs come from each stage, directly or not (workflow/rules/*.smk).
DOWNSTREAM = {  # within the built-in experiment, what `snakemake -c2` plans
    "states": {
        *("rollout", "gather", "failures", "analysis", "figures", "manifest", "report"),
        *("seal", "crate"),
    },
    "rollout": {"gather", "failures", "analysis", "figures", "manifest", "report", "seal", "crate"},
    "gather": {"failures", "analysis", "figures", "manifest", "report", "seal", "crate"},
    "failures": {"manifest", "report", "seal", "crate"},
    "analysis": {"figures", "manifest", "report", "seal", "crate"},
    "figures": {"report", "seal", "crate"},
    "manifest": {"report", "seal", "crate"},
    "report": {"seal", "crate"},
    "seal": {"crate"},
    "crate": set(),
    "sensitivity": set(),  # the studies' stages are not part of `snakemake -c2`
    "dose_response": set(),
    **{stage: set() for stage in BENCHMARK_STAGES},  # nor a benchmark's
    **{stage: set() for stage in PILOT_STAGES},  # nor the pilot's (`snakemake -c2 pilot`)
}


@pytest.fixture
def own_package(built, tmp_path) -> tuple[Path, dict[str, str]]:
    """A copy of the built experiment with a copy of `src/`, and the env that imports it."""
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    shutil.copytree(REPO_ROOT / "src", workdir / "src", ignore=shutil.ignore_patterns("*.pyc"))
    return workdir, {"PYTHONPATH": str(workdir / "src")}


def test_touching_every_file_reruns_nothing(own_package):
    workdir, env = own_package
    for path in workdir.rglob("*"):
        if path.is_file() and ".snakemake" not in path.parts:
            path.touch()
    assert planned_jobs(workdir, env=env) == {}


def test_editing_one_module_reruns_the_stages_importing_it_and_verify_names_it(
    own_package, stage_runtime_imports
):
    workdir, env = own_package
    # a module that no stage imports only inside a function: the stages importing it are then
    # those a fresh interpreter holds it for (`mjtrial.stats.paired` is also imported by the
    # manifest inside a function, through the `mjtrial.stats` package)
    module = "mjtrial.stats.comparisons"
    importing = {stage for stage in STAGES if module in stage_runtime_imports[stage]}
    assert importing, f"no stage imports {module}: pick another module for this test"
    with open(workdir / "src" / "mjtrial" / "stats" / "comparisons.py", "a") as f:
        f.write("\n# an edit\n")

    # the built-in experiment runs no study, benchmark, pilot or stopping rule's look
    built_in = importing - {
        "sensitivity",
        "dose_response",
        "look",
        *BENCHMARK_STAGES,
        *PILOT_STAGES,
    }
    expected = built_in | {d for s in built_in for d in DOWNSTREAM[s]}
    jobs = planned_jobs(workdir, env=env)
    assert set(jobs) - {"all"} == expected

    proc = subprocess.run(
        # the copy's own package on the path; no re-simulation of the 24 episodes: they check
        # the tables' rows, not which code the stamps record
        [sys.executable, "-m", "mjtrial.cli", "verify", "--resimulate", "0"]
        + ["--repo-root", str(workdir)],
        capture_output=True,
        text=True,
        env=os.environ | env,
        timeout=300,
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("stale")]
    named = {line.split()[1].rstrip(":") for line in lines if f"code changed: {module}" in line}
    assert proc.returncode != 0 and named
    # Every output of an importing stage, and only those, names the module.
    for line in proc.stdout.splitlines():
        path = line.split()[1].rstrip(":") if line.startswith(("ok", "stale")) else None
        if path is None or path.endswith("/registration.json"):
            continue  # no stage writes the registration: the register job, which has no code param
        assert (path in named) == (_stage_of(path) in importing), line


def _stage_of(path: str) -> str:
    """The stage that writes a results path of the built-in experiment."""
    rel = path.split("research_mode/", 1)[1]
    if rel.startswith("rollouts/"):  # a shard's table or recordings, or the gathered files
        return "rollout" if "/shard-" in rel else "gather"
    if rel.startswith("replay/"):
        return "failures"
    if rel.startswith("analysis/"):
        return "analysis"
    if rel == "manifest.json":
        return "manifest"
    if rel == "states.parquet":
        return "states"
    if rel == "seal.json":
        return "seal"
    if rel == "ro-crate-metadata.json" or rel == "source":
        return "crate"
    if rel.startswith("figures/"):
        return "figures"
    return "report"


def _fresh_closure(monkeypatch, cache_file: Path, roots: set[str]) -> list[str]:
    """module_closure in a state as a new process would have it, the cache at `cache_file`."""
    monkeypatch.setattr(codehash, "IMPORTS_CACHE", cache_file)
    codehash._statements_cache.cache_clear()
    codehash._module_imports.cache_clear()
    return codehash.module_closure(roots)


def test_the_kept_import_statements_give_the_closure_parsing_gives(monkeypatch, tmp_path):
    roots = {"mjtrial.stages.rollout", "mjtrial.verify"}
    cache_file = tmp_path / "imports.json"
    # the reference: every module parsed, no cache to read (a folder where the file should be)
    (tmp_path / "unreadable.json").mkdir()
    parsed = _fresh_closure(monkeypatch, tmp_path / "unreadable.json", roots)
    assert _fresh_closure(monkeypatch, cache_file, roots) == parsed  # written ...
    kept = json.loads(cache_file.read_text())
    rollout = (codehash.module_file("mjtrial.stages.rollout")).read_bytes()
    key = hashlib.sha256(rollout).hexdigest()
    assert [tuple(s[:2]) for s in kept[key]] == [
        s[:2] for s in codehash.import_statements(rollout.decode())
    ]
    assert _fresh_closure(monkeypatch, cache_file, roots) == parsed  # ... and read
    # the cache is what is read: an entry for the module's content is taken as it stands
    kept[key] = [["mjtrial.config.budget", 0, []]]
    cache_file.write_text(json.dumps(kept))
    closure = _fresh_closure(monkeypatch, cache_file, {"mjtrial.stages.rollout"})
    assert "mjtrial.config.budget" in closure
    # an edited module has another key: its kept statements are never used
    assert kept.pop(key)
    kept[hashlib.sha256(rollout + b"\n").hexdigest()] = [["mjtrial.config.budget", 0, []]]
    cache_file.write_text(json.dumps(kept))
    assert _fresh_closure(monkeypatch, cache_file, roots) == parsed
    # a damaged cache is only slower
    cache_file.write_text('{"truncated": [["mjtrial.bud')
    assert _fresh_closure(monkeypatch, cache_file, roots) == parsed
    codehash._statements_cache.cache_clear()
    codehash._module_imports.cache_clear()
