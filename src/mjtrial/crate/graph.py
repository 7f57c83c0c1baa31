"""A results folder as a Provenance Run Crate (profile 0.5, on RO-Crate 1.1), built with the
`rocrate` library (ro-crate-py) from a `RunRecord`.

What the crate holds (ids relative to its root; `source/` is the copy of the sources):

- the workflow, `source/Snakefile`: `ComputationalWorkflow` (and `HowTo`), the crate's
  `mainEntity`, in Snakemake; its version is the git commit the crate was written at (with
  the diff's sha256 when the checkout was dirty); its tools (`hasPart`) are the pipeline's
  stages that ran (`#tool/<stage>`, each pointing at its script), its steps (`step`) one
  `HowToStep` per stage;
- one `CreateAction` per job behind a sealed output (`#job/<its stamp's rule>`), each rollout
  shard its own: `instrument` its stage's tool, `object` the files its stamp records and its
  config slice and seeds as `PropertyValue`s, `result` its outputs, with the job's start and
  end; a `ControlAction` per job ties it to its step;
- the run as a whole: a `CreateAction` of the workflow (`#run`) and an `OrganizeAction` of
  Snakemake (`#snakemake-run`) over the `ControlAction`s; each library version the stamps
  record is a `SoftwareApplication`, required by the tools that ran with it;
- every file with its `sha256` (a term of the workflow-run context) and `contentSize`: the
  sealed outputs with the sha256 their seal records, the seals, the sources; each shard's
  recordings one `Dataset` whose sha256 is mjtrial's digest of the folder.

The same record also gives the crate at the root of `mjtrial crate --zip`'s archive, where the
results lie under `results/<experiment>/` and the sources at the top (`Ids`).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import quote, unquote

from rocrate.model import ContextEntity
from rocrate.rocrate import ROCrate

from mjtrial.crate.record import RunRecord, input_records
from mjtrial.crate.stamp import STAMP_ID, stamp_entity
from mjtrial.files.layout import CRATE_FILE, STAGES

RO_CRATE_VERSION = "1.1"
WORKFLOW_RUN_CONTEXT = "https://w3id.org/ro/terms/workflow-run/context"
# The profiles the crate conforms to: Provenance Run Crate 0.5 and those it extends.
PROFILES = {
    "https://w3id.org/ro/wfrun/process/0.5": ("Process Run Crate", "0.5"),
    "https://w3id.org/ro/wfrun/workflow/0.5": ("Workflow Run Crate", "0.5"),
    "https://w3id.org/ro/wfrun/provenance/0.5": ("Provenance Run Crate", "0.5"),
    "https://w3id.org/workflowhub/workflow-ro-crate/1.0": ("Workflow RO-Crate", "1.0"),
}
# The validator's profiles expect the status as the IRI's text, not as a reference.
COMPLETED = "http://schema.org/CompletedActionStatus"
BIOSCHEMAS_WORKFLOW = "https://bioschemas.org/profiles/ComputationalWorkflow/1.0-RELEASE"

# The libraries a stamp records (`mjtrial.provenance.stamp`): key -> (name, PyPI project).
_LIBRARIES = {
    "python": ("Python", None),
    "mujoco": ("MuJoCo", "mujoco"),
    "numpy": ("NumPy", "numpy"),
    "snakemake": ("Snakemake", "snakemake"),
    "rerun-sdk": ("Rerun SDK", "rerun-sdk"),
    "gitpython": ("GitPython", "GitPython"),
    "pyarrow": ("PyArrow", "pyarrow"),
    "mjtrial": ("mjtrial", None),
}
# Media types by file suffix (`encodingFormat`); what is not listed is octet-stream.
_FORMATS = {
    ".parquet": "application/vnd.apache.parquet",
    ".json": "application/json",
    ".jsonld": "application/ld+json",
    ".md": "text/markdown",
    ".png": "image/png",
    ".svg": "image/svg+xml",
    ".py": "text/x-python",
    ".smk": "text/x-snakemake",
    ".yaml": "application/yaml",
    ".yml": "application/yaml",
    ".xml": "application/xml",
    ".rst": "text/x-rst",
    ".toml": "application/toml",
    ".txt": "text/plain",
}
_NAMED_FORMATS = {"Snakefile": "text/x-snakemake"}
PROFILE = "profiles/default/config.yaml"  # Snakemake's profile, what the workflow runs with


def encoding_format(name: str) -> str:
    """A file's media type from its name (Rerun's .rrd has none registered: octet-stream)."""
    base = name.rsplit("/", 1)[-1]
    suffix = "." + base.rsplit(".", 1)[-1].lower() if "." in base else ""
    return _NAMED_FORMATS.get(base) or _FORMATS.get(suffix, "application/octet-stream")


def _one_or_many(refs: list[dict[str, str]]) -> Any:
    """A single reference alone, several as a list (RO-Crate 1.1 prefers single values)."""
    return refs[0] if len(refs) == 1 else refs


_UNLICENSED = (
    "No license chosen: the run's config sets no license, so the results may not be reused "
    "without asking their authors."
)


def entity_id(path: str) -> str:
    """A data entity's @id from its path relative to the crate's root: percent-encoded once
    (RO-Crate 1.1: an @id is a URI reference), as ro-crate-py encodes the `dest_path` it is
    given (`quote`, "/" kept). `entity_path` reads it back."""
    return quote(path)


def entity_path(identifier: str) -> str:
    """The path relative to the crate's root of a data entity's @id (`entity_id` undone)."""
    return unquote(identifier)


@dataclass(frozen=True)
class Ids:
    """Where the crate's files are, relative to its root: the results folder's files under
    `data` ("" in the folder's own crate), the copy of the sources under `source`. Paths, not
    yet percent-encoded: `entity_id` gives each one's @id."""

    results: str  # the results folder relative to the repository, as the seals name it
    data: str = ""
    source: str = "source/"

    def output(self, path: str, *, folder: bool = False) -> str:
        rel = path.removeprefix(self.results.rstrip("/") + "/")
        return self.data + rel + ("/" if folder else "")

    def of_source(self, rel: str) -> str:
        return self.source + rel


def _job_id(rule: str) -> str:
    return "#job/" + quote(rule.replace("#", "/shard-"), safe=":/._-")


def _flatten(value: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """A config slice as (dotted key, value) pairs: nested mappings flattened, lists and
    null as JSON text (a JSON-LD list would be a set, and null no value at all); keys in
    sorted order, as a stamp stores them, so the crate job and verify list them alike."""
    if isinstance(value, Mapping):
        for key, inner in sorted(value.items()):
            yield from _flatten(inner, f"{prefix}.{key}" if prefix else str(key))
    elif isinstance(value, (bool, int, float, str)):
        yield prefix, value
    else:
        yield prefix, json.dumps(value, sort_keys=True)


def _studies(seals: Mapping[str, Any]) -> list[str]:
    """The studies among the seals a crate covers (`seal_<study>.json`)."""
    names = [s.rsplit("/", 1)[-1] for s in seals]
    return [n.removeprefix("seal_").removesuffix(".json") for n in names if n.startswith("seal_")]


def _git_version(stamp: Mapping[str, Any], source_sha256: str) -> str:
    git = stamp.get("git") or {}
    if not git.get("available"):
        return f"sha256:{source_sha256} (no git checkout; the sha256 of source/)"
    if git.get("dirty"):
        return f"{git['commit']}+dirty.{git['diff_sha256']}"
    return str(git["commit"])


class _Builder:
    def __init__(self, record: RunRecord, ids: Ids, script_docs: Mapping[str, str]) -> None:
        self.record, self.ids, self.docs = record, ids, script_docs
        self.crate = ROCrate(version=RO_CRATE_VERSION)
        self.crate.metadata.extra_contexts.append(WORKFLOW_RUN_CONTEXT)
        jobs = {**record.jobs(), "crate": []}
        order = list(STAGES)
        self.jobs = dict(
            sorted(jobs.items(), key=lambda job: (order.index(job[0].split(":")[0]), job[0]))
        )

    # -- entities ------------------------------------------------------------------------------
    def entity(self, identifier: str, properties: dict[str, Any]) -> ContextEntity:
        existing = self.crate.get(identifier)
        return existing or self.crate.add(ContextEntity(self.crate, identifier, properties))

    def ref(self, identifier: str) -> dict[str, str]:
        return {"@id": identifier}

    def data_ref(self, path: str) -> dict[str, str]:
        """A reference to the data entity of `path` (relative to the crate's root)."""
        return self.ref(entity_id(path))

    def add_data_entity(self, path: str, properties: dict[str, Any], *, folder: bool) -> Any:
        """A File or Dataset at `path`, its @id percent-encoded once by ro-crate-py; the id
        is checked to be the one `data_ref` gives (encoded twice, a name with a space or a
        non-ASCII letter was an id no reference pointed at)."""
        add = self.crate.add_dataset if folder else self.crate.add_file
        entity = add(dest_path=path, properties=properties)
        if entity.id != entity_id(path):
            raise ValueError(f"{path}: ro-crate-py gave it the @id {entity.id!r}")
        return entity

    def parameter(self, name: str, value: Any) -> dict[str, str]:
        digest = hashlib.sha256(json.dumps([name, value]).encode()).hexdigest()[:12]
        identifier = "#param/" + quote(name, safe="._-") + "/" + digest
        self.entity(identifier, {"@type": "PropertyValue", "name": name, "value": value})
        return self.ref(identifier)

    def library(self, key: str, version: str) -> dict[str, str]:
        name, project = _LIBRARIES.get(key, (key, key))
        if key == "python":
            identifier = (
                f"https://www.python.org/downloads/release/python-{version.replace('.', '')}/"
            )
            url = "https://www.python.org/"
        elif key == "mjtrial":
            identifier, url = f"#mjtrial-{version}", entity_id(self.ids.of_source(""))
        else:
            identifier = f"https://pypi.org/project/{project}/{version}/"
            url = identifier
        properties = {"@type": "SoftwareApplication", "name": name, "version": version}
        self.entity(identifier, {**properties, "url": self.ref(url)})
        return self.ref(identifier)

    # -- data ---------------------------------------------------------------------------------
    def add_data(self) -> None:
        rec, ids = self.record, self.ids
        for path, out in rec.outputs.items():
            identifier = ids.output(path, folder=out.folder)
            if out.folder:
                self.add_data_entity(
                    identifier,
                    folder=True,
                    properties={
                        "name": path.rsplit("/", 1)[-1],
                        "description": (
                            "A folder written as one output (a shard's Rerun recordings, one "
                            ".rrd per episode, and their viewer layout); its sha256 is "
                            "mjtrial's digest of the folder: each file's path in it and "
                            "sha256, in name order (mjtrial.provenance.file_sha256)."
                        ),
                        "sha256": out.sha256,
                    },
                )
                continue
            properties = {
                "name": path.rsplit("/", 1)[-1],
                "sha256": out.sha256,
                "contentSize": str(out.size),
                "encodingFormat": encoding_format(path),
            }
            self.add_data_entity(identifier, properties, folder=False)
        if ids.data:  # the archive's crate: the folder's own crate and its copy are files of it
            self.add_data_entity(
                ids.output(f"{rec.results}/{CRATE_FILE}"),
                folder=False,
                properties={
                    "name": "The results folder's own crate",
                    "encodingFormat": "application/ld+json",
                },
            )
        self.add_data_entity(
            ids.output(f"{rec.results}/source", folder=True),
            folder=True,
            properties={
                "name": "source",
                "description": (
                    "The workflow's sources as they ran (Snakefile, workflow/, config/, models/, "
                    "tasks/, profiles/, pyproject.toml, README.md and the mjtrial package as "
                    "src/mjtrial/), copied by the crate job; its sha256 is mjtrial's digest of "
                    "the folder."
                ),
                "sha256": rec.source_sha256,
            },
        )
        if rec.registration is not None:
            self.add_data_entity(
                ids.output(rec.registration.path),
                folder=False,
                properties={
                    "name": rec.registration.path.rsplit("/", 1)[-1],
                    "description": (
                        "The registered design (mjtrial.design.registration): the design record "
                        "frozen before the run, its earlier registrations and the deviations "
                        "seen; no job's output, read by the manifest and the seal."
                    ),
                    "sha256": rec.registration.sha256,
                    "contentSize": str(rec.registration.size),
                    "encodingFormat": "application/json",
                },
            )
        for rel, (sha, size) in rec.sources.items():
            if rel == "Snakefile":
                continue  # the workflow, added with its own types
            self.add_data_entity(
                ids.of_source(rel),
                folder=False,
                properties={
                    "name": rel,
                    "sha256": sha,
                    "contentSize": str(size),
                    "encodingFormat": encoding_format(rel),
                },
            )

    def input_ref(self, path: str) -> dict[str, str] | None:
        """A stamp's recorded input as an entity of the crate: an output or seal, or a file
        of the copy of the sources (the model, the task); None for anything else."""
        rec = self.record
        if path in rec.outputs:
            return self.data_ref(self.ids.output(path, folder=rec.outputs[path].folder))
        if path in rec.sources:
            return self.data_ref(self.ids.of_source(path))
        if rec.registration is not None and path == rec.registration.path:
            return self.data_ref(self.ids.output(path))
        return None

    # -- the workflow, its tools and steps ----------------------------------------------------
    def add_workflow(self) -> None:
        rec = self.record
        versions = rec.crate_stamp.get("versions", {})
        sha, size = rec.sources["Snakefile"]
        self.workflow = self.crate.add_workflow(
            dest_path=self.ids.of_source("Snakefile"),
            main=True,
            lang="snakemake",
            lang_version=versions.get("snakemake"),
            properties={
                "@type": ["File", "SoftwareSourceCode", "ComputationalWorkflow", "HowTo"],
                "name": "mjtrial workflow (Snakefile)",
                "description": (
                    "The mjtrial pipeline: seeded paired states, rollouts in shards, failures, "
                    "analysis, manifest, report and seal, and the studies; or a benchmark's "
                    "training, evaluation, solvability and closest calls; its rules are in "
                    "workflow/rules/, their scripts in workflow/scripts/, the code they call in "
                    "src/mjtrial/."
                ),
                "version": _git_version(rec.crate_stamp, rec.source_sha256),
                "conformsTo": self.ref(BIOSCHEMAS_WORKFLOW),
                "sha256": sha,
                "contentSize": str(size),
                "encodingFormat": encoding_format("Snakefile"),
                "url": self.data_ref(self.ids.of_source("")),
            },
        )
        stages = sorted(
            {rule.split(":")[0] for rule in self.jobs}, key=lambda s: list(STAGES).index(s)
        )
        tools, steps = [], []
        for position, stage in enumerate(stages):
            tools.append(self.ref(self.add_tool(stage)))
            step = f"#step/{stage}"
            self.entity(
                step,
                {
                    "@type": "HowToStep",
                    "name": stage,
                    "position": position,
                    "workExample": tools[-1],
                },
            )
            steps.append(self.ref(step))
        self.workflow["hasPart"] = tools
        self.workflow["step"] = steps

    def add_tool(self, stage: str) -> str:
        """A stage's tool: its script, its code's digest, the libraries its jobs ran with."""
        script = STAGES[stage].script_path
        jobs = [rule for rule in self.jobs if rule.split(":")[0] == stage]
        stamps = [self.job_stamp(rule) for rule in jobs]
        digests = sorted({str(s.get("extra", {}).get("code_sha256")) for s in stamps})
        libraries = sorted(
            {(k, v) for s in stamps for k, v in s.get("versions", {}).items() if v is not None}
        )
        identifier = f"#tool/{stage}"
        properties: dict[str, Any] = {
            "@type": "SoftwareApplication",
            "name": f"mjtrial stage {stage}",
            "description": self.docs.get(script)
            or f"The {stage} stage (mjtrial.stages, through {script}).",
            "version": " ".join(f"sha256:{d}" for d in digests),
            "softwareRequirements": [self.library(k, v) for k, v in libraries],
        }
        if script in self.record.sources:
            properties["url"] = self.data_ref(self.ids.of_source(script))
        self.entity(identifier, properties)
        return identifier

    def job_stamp(self, rule: str) -> Mapping[str, Any]:
        if rule == "crate":
            return self.record.crate_stamp
        return self.record.stamps[self.jobs[rule][0]]

    # -- the jobs -----------------------------------------------------------------------------
    def add_jobs(self) -> list[dict[str, str]]:
        controls = []
        for rule in self.jobs:
            stamp = self.job_stamp(rule)
            stage = rule.split(":")[0]
            job = _job_id(rule)
            objects = []
            for record in input_records(stamp.get("inputs", {})):
                ref = self.input_ref(record.get("path", ""))
                if ref is not None and ref not in objects:
                    objects.append(ref)
            objects += [self.parameter(k, v) for k, v in _flatten(stamp.get("config_slice"))]
            objects += [self.parameter(f"seed.{k}", v) for k, v in stamp.get("seeds", {}).items()]
            if rule == "crate":
                objects.append(self.ref(STAMP_ID))
                self.entity(STAMP_ID, stamp_entity(dict(stamp)))
                results = [
                    self.data_ref(
                        self.ids.output(f"{self.record.results}/{CRATE_FILE}")
                        if self.ids.data
                        else CRATE_FILE
                    ),
                    self.data_ref(self.ids.output(f"{self.record.results}/source", folder=True)),
                ]
            else:
                results = [self.input_ref(p) for p in self.jobs[rule]]
            properties: dict[str, Any] = {
                "@type": "CreateAction",
                "name": rule,
                "description": self.job_description(rule, stamp),
                "actionStatus": COMPLETED,
            }
            start, end = self.record.times.get(rule, (None, None))
            if start is not None:
                properties["startTime"] = start
            if end is not None:
                properties["endTime"] = end
            action = self.crate.add_action(
                self.crate.get(f"#tool/{stage}"),
                identifier=job,
                object=_one_or_many(objects),
                result=_one_or_many(results),
                properties=properties,
            )
            self.actions.append(action)
            control = f"#control/{job.removeprefix('#job/')}"
            self.entity(
                control,
                {
                    "@type": "ControlAction",
                    "name": f"orchestrate {rule}",
                    "instrument": self.ref(f"#step/{stage}"),
                    "object": self.ref(job),
                    "actionStatus": COMPLETED,
                },
            )
            controls.append(self.ref(control))
        return controls

    def job_description(self, rule: str, stamp: Mapping[str, Any]) -> str:
        git = stamp.get("git") or {}
        code = (
            f"code at commit {git['commit']}"
            + (" with uncommitted changes" if git.get("dirty") else "")
            if git.get("available")
            else "code outside a git checkout"
        )
        return (
            f"The job stamped {rule!r}: stage {rule.split(':')[0]} "
            f"(mjtrial.stages), {code}; its outputs carry this stamp "
            "(`mjtrial provenance FILE` prints it)."
        )

    # -- the run ------------------------------------------------------------------------------
    def add_run(self, controls: list[dict[str, str]]) -> None:
        rec = self.record
        starts = [t[0] for t in rec.times.values() if t[0]]
        ends = [t[1] for t in rec.times.values() if t[1]]
        span = {}
        if starts:
            span["startTime"] = min(starts)
        if ends:
            span["endTime"] = max(ends)
        run_inputs = []
        # The run's config file, Snakemake's profile (its settings decide what reruns), and
        # the source files the jobs read (the model, the task).
        config_file = (rec.manifest.get("rerun") or {}).get("config_file")
        for path in [config_file, PROFILE, *self.source_inputs()]:
            ref = self.input_ref(path) if isinstance(path, str) else None
            if ref is not None and ref not in run_inputs:
                run_inputs.append(ref)
        command_line = (rec.manifest.get("rerun") or {}).get("command_line") or {}
        run_inputs += [self.parameter(f"config.{k}", v) for k, v in _flatten(command_line)]
        results = [self.input_ref(p) for p in rec.outputs]
        experiment = rec.results.rstrip("/").rsplit("/", 1)[-1]
        kind = "benchmark" if self.is_benchmark() else "experiment"
        self.crate.add_action(
            self.workflow,
            identifier="#run",
            object=run_inputs,
            result=results,
            properties={
                "@type": "CreateAction",
                "name": f"Run of the mjtrial workflow: {kind} {experiment}",
                "description": (
                    "Every job behind the sealed outputs of the results folder, whichever "
                    "Snakemake call ran it: "
                    + ", ".join(
                        [(rec.manifest.get("rerun") or {}).get("command", "snakemake -c2")]
                        + [f"snakemake -c2 {study}" for study in _studies(rec.seals)]
                    )
                    + "."
                ),
                "actionStatus": COMPLETED,
                **span,
            },
        )
        snakemake = rec.crate_stamp.get("versions", {}).get("snakemake")
        engine = self.library("snakemake", snakemake) if snakemake else None
        self.entity(
            "#snakemake-run",
            {
                "@type": "OrganizeAction",
                "name": f"Snakemake {snakemake or ''}".strip(),
                "description": "The workflow engine's runs that made the jobs of #run.",
                "instrument": engine,
                "object": _one_or_many(controls),
                "result": self.ref("#run"),
                "actionStatus": COMPLETED,
                **span,
            },
        )
        self.crate.root_dataset["mentions"] = [self.ref("#run"), self.ref("#snakemake-run")] + [
            self.ref(a.id) for a in self.actions
        ]

    def is_benchmark(self) -> bool:
        """A benchmark's results (its summary's job is the stage `benchmark`)."""
        return any(rule.split(":")[0] == "benchmark" for rule in self.jobs)

    def source_inputs(self) -> list[str]:
        """The source files the jobs read (model, task), in the order they first appear."""
        seen: dict[str, None] = {}
        for rule in self.jobs:
            for record in input_records(self.job_stamp(rule).get("inputs", {})):
                path = record.get("path", "")
                if path in self.record.sources:
                    seen.setdefault(path)
        return list(seen)

    # -- the root -----------------------------------------------------------------------------
    def add_root(self) -> None:
        rec = self.record
        root = self.crate.root_dataset
        design = rec.manifest.get("design") or {}
        experiment = rec.results.rstrip("/").rsplit("/", 1)[-1]
        studies = _studies(rec.seals)
        root["name"] = f"mjtrial results: {experiment}"
        question = design.get("question") or "an mjtrial experiment"
        hypothesis = design.get("hypothesis")
        parts = (
            "a benchmark's: each task's development and evaluation states, solvability, "
            "training, evaluation, summary, closest calls, report, figures, seal"
            if self.is_benchmark()
            else "states, rollouts, analysis, manifest, report, figures, seal"
        )
        root["description"] = (
            f"{question}"
            + (f" Hypothesis: {hypothesis}" if hypothesis else "")
            + f" The results of a run of the mjtrial workflow ({parts})"
            + (f" and its studies ({', '.join(studies)})" if studies else "")
            + ", with the sources that made them."
        )
        root["datePublished"] = (
            rec.times.get("crate", (None, None))[1] or rec.crate_stamp["created_utc"]
        )
        described = rec.crate_stamp.get("config_slice") or {}
        if described.get("authors"):
            root["author"] = [self.author(a) for a in described["authors"]]
        if described.get("keywords"):
            root["keywords"] = list(described["keywords"])
        license_ = described.get("license")
        if license_ is None:
            root["license"] = _UNLICENSED
        else:
            identifier = license_ if "://" in license_ else f"https://spdx.org/licenses/{license_}"
            self.entity(
                identifier,
                {
                    "@type": "CreativeWork",
                    "name": license_,
                    "description": "The license the run's config gives its results.",
                },
            )
            root["license"] = self.ref(identifier)
        for identifier, (name, version) in PROFILES.items():
            self.entity(
                identifier, {"@type": ["CreativeWork", "Profile"], "name": name, "version": version}
            )
        root["conformsTo"] = [self.ref(i) for i in PROFILES]

    def author(self, author: Mapping[str, str]) -> dict[str, str]:
        """A `Person` of the config's `provenance.authors`: its ORCID iD as its @id if given."""
        identifier = author.get("orcid") or "#author/" + quote(author["name"], safe="")
        properties = {"@type": "Person", "name": author["name"]}
        if author.get("affiliation"):
            properties["affiliation"] = author["affiliation"]
        self.entity(identifier, properties)
        return self.ref(identifier)

    def build(self) -> dict[str, Any]:
        self.actions: list[Any] = []
        self.add_root()
        self.add_data()
        self.add_workflow()
        controls = self.add_jobs()
        self.add_run(controls)
        return self.crate.metadata.generate()


def crate_metadata(
    record: RunRecord, *, ids: Ids | None = None, scripts: Mapping[str, str] | None = None
) -> dict[str, Any]:
    """The crate's JSON-LD (`@context` and `@graph`) for `record`.

    `ids` places the files (default: the results folder's own crate); `scripts` gives each stage
    script's summary by its path (`workflow/scripts/<script>.py`), as `script_summaries` reads
    them from the copy of the sources.
    """
    ids = ids or Ids(results=record.results)
    return _Builder(record, ids, scripts or {}).build()
