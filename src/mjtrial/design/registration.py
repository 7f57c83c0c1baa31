"""The registered design: frozen before any rollout, compared with every later run.

`results/<experiment>/registration.json` holds the design record (the config's sections that
make the design, verbatim, and the hashes of the task's files and of the model's closure), its
sha256 and the UTC time it was registered, the power plan of that design, every earlier
registration (`mjtrial register --again` moves the current one there, never drops it).
`deviations.json` beside it holds each design that differed from the registration, first seen
when a run started, with what changed and whether results existed then.

The design is registered once, when the first evaluation rollout is about to start: by the
`register` job, which runs after the states job (after every check that can refuse the
design) and before every rollout, never on a dry run nor for the `dev` and `pilot` targets. It
never rewrites a registration: one that Snakemake removed to rerun the job (`--forceall`) is
put back from the run's snapshot. Each registration records what results existed when it was
made (`results_witness`: in the folder, in Snakemake's records, in the crate), so that a
registration made after results, by `mjtrial register --again` or after the file was deleted,
reads so for ever; and its own sha256 (`entry_sha256`), which every stamp made after it
carries (`registration_sha256`): a registration rewritten later disagrees with the outputs
made before it. A deviation is noted in `onstart` (before any job removes the results it
deviates from). The manifest records the registration and the run's deviations, the seal
records the file's sha256, `mjtrial verify` checks both.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import shutil
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from mjtrial import REPO_ROOT, provenance
from mjtrial.files.layout import Layout

# The config sections that make the design, stored verbatim (their keys need not be known
# here: a section added to the config, as `stopping`, is registered when present).
REGISTERED_SECTIONS = (
    "experiment",
    "design",
    "task",
    "model",
    "conditions",
    "states",
    "failure_taxonomy",
    "analysis",
    "stopping",
    "privileged_observations",
)
RULE = "register"
# What a power plan assumes without a pilot (said in the plan and the report).
ASSUMED_DISCORDANT = 0.5


def utc_now() -> str:
    """The time as stamps write it (to the second, UTC), so that the two compare as text."""
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


class RegistrationError(ValueError):
    """A registration that cannot be read or would be overwritten; one line."""


def _canonical(obj: Any) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()


def sha256_of(obj: Any) -> str:
    return hashlib.sha256(_canonical(obj)).hexdigest()


def design_record(config: Mapping[str, Any], *, repo_root: Path = REPO_ROOT) -> dict[str, Any]:
    """The design as registered: its config sections verbatim, and the code and model it runs
    (the success test is the task's code: its files' sha256)."""
    # In here (mujoco): `mjtrial plan` reads registrations without loading a task.
    from mjtrial.task import task_files

    repo_root = Path(repo_root)
    sections = {k: copy.deepcopy(config[k]) for k in REGISTERED_SECTIONS if k in config}
    reference = str(config["task"])
    task = (
        {
            provenance.repo_relative(p, repo_root): provenance.file_sha256(p)
            for p in task_files(repo_root / reference)
        }
        if reference.endswith(".py")
        else reference
    )
    record = {
        "sections": json.loads(json.dumps(sections, default=str)),
        "task_files_sha256": task,
        "model_sha256": provenance.model_sha256(repo_root / config["model"]),
    }
    policies = policy_files_sha256(config, repo_root=repo_root)
    if policies:  # only when a condition names one: a design without is registered as before
        record["policy_files_sha256"] = policies
    return record


def policy_files_sha256(config: Mapping[str, Any], *, repo_root: Path) -> dict[str, str]:
    """The sha256 of every file a design condition's policy runs (the graph, its contract and
    the graph's external data: `policy_file.policy_file_paths`), by path; a file missing is
    recorded as such (the config check says why)."""
    # In here (the policy files' reader loads onnx): `mjtrial plan` reads registrations only.
    from mjtrial.design.conditions import policy_path
    from mjtrial.policy_files.file import policy_file_paths

    out: dict[str, str] = {}
    for condition in (config.get("conditions") or {}).values():
        policy = policy_path(condition or {})
        if policy is None:
            continue
        for path in policy_file_paths(Path(repo_root) / policy):
            key = provenance.repo_relative(path, Path(repo_root))
            out[key] = provenance.file_sha256(path) if path.is_file() else "missing"
    return dict(sorted(out.items()))


def changes(registered: Any, now: Any, prefix: str = "") -> list[dict[str, Any]]:
    """Every difference between two design records: key path, registered value, value now
    (`None` with `absent` for a key on one side only)."""
    if isinstance(registered, Mapping) and isinstance(now, Mapping):
        out: list[dict[str, Any]] = []
        for key in [*registered, *(k for k in now if k not in registered)]:
            path = f"{prefix}.{key}" if prefix else str(key)
            if key not in now:
                out.append(
                    {"key": path, "registered": registered[key], "now": None, "absent": "now"}
                )
            elif key not in registered:
                out.append(
                    {"key": path, "registered": None, "now": now[key], "absent": "registered"}
                )
            else:
                out += changes(registered[key], now[key], path)
        return out
    if registered == now:
        return []
    return [{"key": prefix, "registered": registered, "now": now}]


def deviations(registration: Mapping[str, Any], record: Mapping[str, Any]) -> list[dict[str, Any]]:
    """What the design `record` changes of the registered one, key by key (config keys as
    `design.falsifier.threshold`; code as `task_files_sha256.<file>`, `model_sha256`)."""
    found = changes(registration["current"]["design"], record)
    for change in found:
        change["key"] = change["key"].removeprefix("sections.")
    return found


def read(path: Path) -> dict[str, Any] | None:
    """The registration file, checked: None when there is none."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        data = json.loads(provenance.read_output_text(path))
        data["current"]["design"]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise RegistrationError(f"{path}: not a readable registration ({err})") from err
    return data


def entry_sha256(entry: Mapping[str, Any]) -> str:
    """The sha256 of one registration as it was made (its design, time, plan, reason and the
    results that existed; not when it was superseded): what every stamp made after it records
    as `registration_sha256`."""
    return sha256_of({k: v for k, v in entry.items() if k not in ("sha256", "superseded_utc")})


def problems(data: Mapping[str, Any]) -> list[str]:
    """What is wrong with a registration read back: a record whose hash is not its content's."""
    out = []
    for i, entry in enumerate([data["current"], *data.get("earlier", [])]):
        which = "the registration" if i == 0 else f"earlier registration {i}"
        if sha256_of(entry.get("design")) != entry.get("design_sha256"):
            out.append(f"{which}: its design is not the one its sha256 was taken of")
        if "sha256" in entry and entry_sha256(entry) != entry["sha256"]:
            out.append(f"{which}: it is not the one its sha256 was taken of")
    if sha256_of(_sealed_part(data)) != data.get("sha256"):
        out.append("the registration history is not the one its sha256 was taken of")
    return out


def _sealed_part(data: Mapping[str, Any]) -> dict[str, Any]:
    return {"current": data["current"], "earlier": data.get("earlier", [])}


def _entry(
    config: Mapping[str, Any], *, repo_root: Path, now: str, reason: str | None, layout: Layout
) -> dict[str, Any]:
    record = design_record(config, repo_root=repo_root)
    entry = {
        "registered_utc": now,
        "design_sha256": sha256_of(record),
        "reason": reason,
        "plan": registered_plan(config, layout=layout),
        "results_when_registered": results_witness(layout, workdir=repo_root),
        "design": record,
    }
    return {**entry, "sha256": entry_sha256(entry)}


# What is not a result in a results folder: the registration's own files, the states (drawn
# before the registration, by the states job that checks the design), the development folder
# (the pilot develops the design), the logs, and hidden files (the snapshot, temporaries).
_NOT_RESULTS = ("registration.json", "deviations.json", "states.parquet")
_NOT_RESULT_FOLDERS = ("development", "logs")
# The results whose sha256 a registration keeps, when they exist: what was seen.
_KEY_RESULTS = ("seal.json", "manifest.json", "analysis/summary.json", "report.md")


def _is_result(rel: Path) -> bool:
    parts = rel.parts
    return bool(parts) and not (
        any(p.startswith(".") for p in parts)
        or (len(parts) == 1 and parts[0] in _NOT_RESULTS)
        or parts[0] in _NOT_RESULT_FOLDERS
    )


def results_witness(layout: Layout, *, workdir: Path = Path(".")) -> dict[str, Any]:
    """What results of the experiment exist now, wherever this checkout can see them: files in
    the results folder (a crate's included), and Snakemake's records of outputs under it
    (`.snakemake/metadata`, kept when the files are deleted). `existed`: any; `files`,
    `records`: how many of each; `sha256`: the key results' (`_KEY_RESULTS`, each table of
    `rollouts/`). What it cannot see: a folder deleted with Snakemake's records, or another
    experiment name (a renamed experiment starts a clean record)."""
    from mjtrial.files.safekeeping import METADATA, record_subject  # psutil: for registering only

    workdir = Path(workdir)
    root = layout.root if layout.root.is_absolute() else workdir / layout.root
    files = (
        sorted(p.relative_to(root) for p in root.rglob("*") if p.is_file()) if root.is_dir() else []
    )
    files = [rel for rel in files if _is_result(rel)]
    records = []
    metadata = workdir / METADATA
    if metadata.is_dir():
        try:
            named = root.resolve().relative_to(workdir.resolve())
        except ValueError:
            named = None
        for record in metadata.rglob("*"):
            subject = record_subject(record, metadata) if record.is_file() else None
            if named is not None and subject is not None and named in subject.parents:
                if _is_result(subject.relative_to(named)):
                    records.append(subject)
    hashed = [*_KEY_RESULTS, *(r.as_posix() for r in files if r.parent == Path("rollouts"))]
    return {
        "existed": bool(files or records),
        "files": len(files),
        "records": len(records),
        "sha256": {
            rel: provenance.file_sha256(root / rel) for rel in hashed if (root / rel).is_file()
        },
    }


def _write(data: dict[str, Any], path: Path, *, repo_root: Path, once: bool = False) -> bool:
    """Write the registration; with `once`, only if there is none (an atomic link: of two jobs
    that register at once, one writes). Returns whether it was written."""
    data = {**data, "sha256": sha256_of(_sealed_part(data))}
    stamp = provenance.make_stamp(
        rule=RULE,
        config_slice={"design_sha256": data["current"]["design_sha256"]},
        inputs={},
        repo_dir=repo_root,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    if not once:
        provenance.write_json(data, path, stamp)
        return True
    draft = path.with_name(f".{path.name}.{os.getpid()}.draft")
    provenance.write_json(data, draft, stamp)
    try:
        os.link(draft, path)
    except FileExistsError:
        return False
    finally:
        draft.unlink(missing_ok=True)
    return True


def register(
    config: Mapping[str, Any],
    *,
    layout: Layout,
    repo_root: Path = REPO_ROOT,
    again: bool = False,
    reason: str | None = None,
) -> dict[str, Any]:
    """Register the design of `config` in `layout.registration`; with `again`, the current
    registration moves to `earlier` (with the time it was superseded). Without `again`, an
    existing registration is an error: it is never rewritten silently."""
    path = layout.registration
    existing = read(path)
    if existing is not None and not again:
        raise RegistrationError(
            f"{path}: already registered on {existing['current']['registered_utc']}; "
            "`mjtrial register --again --reason TEXT` registers anew and keeps it in the record"
        )
    now = utc_now()
    data: dict[str, Any] = {
        "current": _entry(config, repo_root=repo_root, now=now, reason=reason, layout=layout),
        "earlier": [],
    }
    if existing is not None:
        superseded = {**existing["current"], "superseded_utc": now}
        data["earlier"] = [superseded, *existing.get("earlier", [])]
    _write(data, path, repo_root=repo_root)
    return data


def ensure_registered(
    config: Mapping[str, Any],
    *,
    layout: Layout,
    repo_root: Path = REPO_ROOT,
    saved: Path | None = None,
) -> dict[str, Any]:
    """The registration, made now when there is none (the `register` job, before the first
    rollout). `saved`: the registration as it was when the run started (the run's snapshot),
    put back when Snakemake removed it to rerun the job (`--forceall`): never registered anew."""
    path = layout.registration
    if not path.exists() and saved is not None and saved.is_file():
        try:
            os.link(saved, path)
        except FileExistsError:
            pass
        except OSError:
            shutil.copy2(saved, path)
    data = read(path)
    if data is not None:
        return data
    now = utc_now()
    entry = _entry(config, repo_root=repo_root, now=now, reason=None, layout=layout)
    _write({"current": entry, "earlier": []}, path, repo_root=repo_root, once=True)
    return read(path) or {}


def results_on_disk(layout: Layout, registered_config: Mapping[str, Any]) -> dict[str, Any]:
    """What results exist now: whether a summary is there, whether the registered design built
    it (its stamp's analysis slice is the registered config's) and its verdict."""
    # In here (the crate and simulator packages): `mjtrial plan` need not load them.
    from mjtrial.stages.stamping import config_slice

    try:
        summary = json.loads(provenance.read_output_text(layout.summary))
        stamp = provenance.read_stamp(layout.summary)
    except (OSError, ValueError):
        return {"results_existed": False}
    try:
        registered = config_slice("analysis", registered_config)
        of_registered = stamp.get("config_slice_sha256") == provenance.config_hash(registered)
    except (KeyError, TypeError):
        of_registered = False
    falsifier = summary.get("falsifier") or {}
    return {
        "results_existed": True,
        "of_registered_design": of_registered,
        "summary_created_utc": stamp.get("created_utc"),
        "verdict": falsifier.get("verdict"),
    }


def registered_config(config: Mapping[str, Any], data: Mapping[str, Any]) -> dict[str, Any]:
    """`config` with the registered sections in place of its own."""
    sections = data["current"]["design"]["sections"]
    out = {k: v for k, v in config.items() if k not in REGISTERED_SECTIONS}
    return {**out, **copy.deepcopy(sections)}


def note_deviation(
    config: Mapping[str, Any], *, layout: Layout, repo_root: Path = REPO_ROOT
) -> dict[str, Any] | None:
    """At a run's start (before any job removes a result): when the design differs from the
    registration and this design was not seen before, add it to `layout.deviations` with the
    time and the results on disk. Returns the entry (None: no deviation). A file of its own:
    the registration's bytes, which the manifest and the seal record, never change by it."""
    data = read(layout.registration)
    if data is None:
        return None
    record = design_record(config, repo_root=repo_root)
    found = deviations(data, record)
    if not found:
        return None
    design_sha = sha256_of(record)
    registered_sha = data["current"]["design_sha256"]
    seen = deviations_seen(layout)
    for entry in seen:
        if entry["design_sha256"] == design_sha and entry["registered_sha256"] == registered_sha:
            return entry
    entry = {
        "design_sha256": design_sha,
        "registered_sha256": registered_sha,
        "first_run_utc": utc_now(),
        "changes": found,
        **results_on_disk(layout, registered_config(config, data)),
    }
    stamp = provenance.make_stamp(
        rule=RULE, config_slice={"design_sha256": design_sha}, inputs={}, repo_dir=repo_root
    )
    provenance.write_json({"deviations_seen": [*seen, entry]}, layout.deviations, stamp)
    return entry


def deviations_seen(layout: Layout) -> list[dict[str, Any]]:
    """The deviations noted so far (`layout.deviations`), oldest first."""
    try:
        seen = json.loads(provenance.read_output_text(layout.deviations))["deviations_seen"]
    except FileNotFoundError:
        return []
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise RegistrationError(f"{layout.deviations}: not a readable record ({err})") from err
    return list(seen)


def registered_plan(
    config: Mapping[str, Any],
    *,
    layout: Layout,
    discordant: float | None = None,
    target: float | None = None,
) -> dict[str, Any]:
    """The power plan of the design: from the pilot's tables when there is a pilot (their
    share of discordant pairs between the falsifier's conditions), else from `discordant`,
    else from ASSUMED_DISCORDANT, each said in the plan's `source`."""
    # In here: the Snakefile registers once, and need not load the planning otherwise.
    from mjtrial.stats.power import power_plan

    falsifier = config["design"]["falsifier"]
    alpha = round(1.0 - float(config["analysis"]["confidence"]), 12)
    source = None
    if discordant is None:
        discordant, source = pilot_discordance(layout, falsifier)
    if discordant is None:
        discordant = ASSUMED_DISCORDANT
        source = (
            f"assumed: half the pairs discordant; {source}"
            if source
            else "assumed: half the pairs discordant; no pilot (snakemake -c2 pilot)"
        )
    elif source is None:
        source = "stated (--discordant)"
    return power_plan(
        pairs=config["states"]["n"],
        alpha=alpha,
        discordant=discordant,
        source=source,
        target=target,
    ).record()


def pilot_discordance(
    layout: Layout, falsifier: Mapping[str, Any]
) -> tuple[float | None, str | None]:
    """The pilot's share of discordant pairs between the falsifier's treatment and baseline
    (`development/rollouts/<condition>.parquet`), with where it comes from; (None, None)
    without a pilot of both; (None, what it was) when the pilot had no discordant pair (a
    share of 0 plans nothing, and the plan says a pilot ran)."""
    tables = [layout.development.rollout_table(falsifier[k]) for k in ("treatment", "baseline")]
    if not all(t.exists() for t in tables):
        return None, None
    import pyarrow.parquet as pq  # the pilot's tables: read when planning only

    from mjtrial.stats.power import discordant_share  # as pyarrow, for planning only

    treatment, baseline = (
        pq.read_table(t, columns=["success"]).column(0).to_pylist() for t in tables
    )
    if len(treatment) != len(baseline) or not treatment:
        return None, None
    share = discordant_share(treatment, baseline)
    rel = layout.development.rollouts_dir().as_posix()
    if share == 0.0:
        return None, f"the pilot's {len(treatment)} pairs of {rel} had none discordant"
    return share, f"the pilot: {len(treatment)} pairs of {rel}"


def first_rollout(stamps: Mapping[str, Any]) -> str | None:
    """When the first rollout of the results was stamped (the manifest's `stamps`)."""
    times = [
        s["created_utc"]
        for s in stamps.values()
        if isinstance(s, Mapping) and str(s.get("rule", "")).split(":")[0] == "rollout"
    ]
    return min(times) if times else None


def manifest_section(
    config: Mapping[str, Any],
    data: Mapping[str, Any],
    *,
    stamps: Mapping[str, Mapping[str, Any]],
    seen: list[Mapping[str, Any]],
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """What the manifest says of the registration: when, whether before every rollout (its
    time against the rollout stamps'), the run's deviations recomputed from the config (with
    when they were first seen and what results existed then) and the registered power plan."""
    current = data["current"]
    first = first_rollout(stamps)
    record = design_record(config, repo_root=repo_root)
    design_sha = sha256_of(record)
    noted = next(
        (
            {k: v for k, v in e.items() if k != "changes"}
            for e in seen
            if e["design_sha256"] == design_sha
            and e["registered_sha256"] == current["design_sha256"]
        ),
        None,
    )
    witnessed = current.get("results_when_registered") or {}
    return {
        "sha256": data.get("sha256"),
        "design_sha256": current["design_sha256"],
        "registered_utc": current["registered_utc"],
        "reason": current.get("reason"),
        "results_when_registered": current.get("results_when_registered"),
        "earlier": [
            {
                k: e.get(k)
                for k in (
                    "registered_utc",
                    "superseded_utc",
                    "design_sha256",
                    "reason",
                    "results_when_registered",
                )
            }
            for e in data.get("earlier", [])
        ],
        "before_any_rollout": first is not None
        and current["registered_utc"] <= first
        and not witnessed.get("existed"),
        "deviations": deviations(data, record),
        "deviation_noted": noted,
        "plan": current.get("plan"),
    }


def lost_deviation_note(layout: Layout) -> str | None:
    """Why the manifest's noted deviation (`deviation_noted`, read from `layout.deviations` when
    it was built) is no longer in `layout.deviations` (missing, or without it), with how to
    restore it; None if it is.
    No rule makes the file, so Snakemake sees nothing to do when it is deleted."""
    try:
        manifest = json.loads(provenance.read_output_text(layout.manifest))
        noted = manifest["registration"]["deviation_noted"]
        seen = deviations_seen(layout)
    except (OSError, ValueError, KeyError, TypeError, RegistrationError):
        return None  # no manifest or no note; an unreadable record is said where it is read
    if not isinstance(noted, Mapping):
        return None
    keys = ("design_sha256", "registered_sha256")
    if any(all(e.get(k) == noted.get(k) for k in keys) for e in seen):
        return None
    state = "missing" if not layout.deviations.exists() else "without the manifest's deviation"
    return (
        f"{state}: {layout.manifest} records the changed design's first run "
        f"at {noted.get('first_run_utc')} (registration.deviation_noted), a fact of that moment "
        "that no job can rebuild; put the file back from a copy of the results folder, or "
        f"`snakemake -c2 -R {layout.manifest}` notes the deviation anew, as first run then"
    )


def stamp_problems(data: Mapping[str, Any], stamps: Mapping[str, Any]) -> list[str]:
    """Outputs whose stamp disagrees with the registration record: a stamp records the
    registration it was made under (`registration_sha256`), which must be one the record holds,
    made before the output and not superseded before it. A registration rewritten (and
    rehashed) after outputs were made is not the one they record."""
    entries = {}
    for entry in [data["current"], *data.get("earlier", [])]:
        if isinstance(entry, Mapping) and "sha256" in entry:
            entries[entry["sha256"]] = entry
    out = []
    for path, stamp in sorted(stamps.items()):
        held = stamp.get("registration_sha256") if isinstance(stamp, Mapping) else None
        if held is None:
            continue
        entry = entries.get(held)
        made = str(stamp.get("created_utc", ""))
        if entry is None:
            out.append(
                f"{path} was made under registration {str(held)[:12]}, which the record does not "
                "hold: the registration was rewritten after it"
            )
        elif made < entry["registered_utc"] or made > entry.get("superseded_utc", made):
            out.append(
                f"{path} was made on {made} under registration {held[:12]}, which the record "
                f"dates {entry['registered_utc']} to {entry.get('superseded_utc', 'now')}"
            )
    return out


def rewritten_registration(layout: Layout) -> list[str]:
    """At a run's start: what the outputs' stamps (the manifest's copies) say against the
    registration on disk (`stamp_problems`); [] without a registration or a manifest."""
    data = read(layout.registration)
    try:
        manifest = json.loads(provenance.read_output_text(layout.manifest))
    except (OSError, ValueError):
        return []
    if data is None or not isinstance(manifest, Mapping):
        return []
    return stamp_problems(data, manifest.get("stamps") or {})
