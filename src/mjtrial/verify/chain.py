"""The checks of `mjtrial verify` on stamps already read: no file is opened here.

:func:`check_stamps` judges every output from its stamp, the stamps of its inputs and the
sha256 of each file now; :class:`VerifyReport` holds the verdicts.
"""

from __future__ import annotations

import json
import posixpath
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from enum import Enum
from pathlib import Path
from typing import Any

from mjtrial import REPO_ROOT, provenance
from mjtrial.files import codehash
from mjtrial.files.layout import CONDITION_STAGES, STAGES
from mjtrial.sim.simenv import VERSION_KEY
from mjtrial.stages.stamping import config_slice, stage_code
from mjtrial.task import task_files

__all__ = [
    "STAMPED_SUFFIXES",
    "Current",
    "OutputResult",
    "Skipped",
    "Status",
    "VerifyReport",
    "check_stamps",
    "dict_diff",
    "parse_rule",
]

# Suffixes of files that carry a stamp (see mjtrial.provenance); other files (logs) are ignored.
STAMPED_SUFFIXES = (".parquet", ".json", ".md", ".png", ".svg", ".rrd")

# Pipeline order, for sorting the report.
_STAGE_ORDER = tuple(STAGES)

# How many file names a reason lists before "and N more".
_NAMES_SHOWN = 3


class Status(Enum):
    """The verdict on one output."""

    OK = "ok"
    STALE = "stale"
    TAMPERED = "tampered"
    MISSING = "missing"
    # differs from its re-simulation, and two re-simulations disagree: the task's code is not a
    # function of its arguments, so the run cannot be reproduced (no sign of tampering)
    IRREPRODUCIBLE = "irreproducible"


@dataclass(frozen=True)
class OutputResult:
    """One output's verdict; ``path`` is repository-relative (POSIX) as stamps record it."""

    path: str
    status: Status
    reasons: tuple[str, ...] = ()
    rule: str | None = None

    def line(self) -> str:
        """``ok  <path>``, ``stale  <path>: <why>``, ``tampered  <path>: <why>``, ..."""
        head = f"{self.status.value}  {self.path}"
        return f"{head}: {'; '.join(self.reasons)}" if self.reasons else head


@dataclass(frozen=True)
class Skipped:
    """A stamped file that no pipeline rule makes (e.g. an ``mjtrial replay`` recording)."""

    path: str
    reason: str

    def line(self) -> str:
        return f"skipped  {self.path}: {self.reason}"


@dataclass(frozen=True)
class VerifyReport:
    """The verdict on every output of a results folder, plus warnings that are no failure."""

    results_dir: str
    outputs: tuple[OutputResult, ...]
    warnings: tuple[str, ...] = ()
    skipped: tuple[Skipped, ...] = ()
    checks: tuple[str, ...] = ()  # what was checked beyond the stamps (recomputation)
    unchecked: tuple[str, ...] = ()  # checks that could not run (the check line says why)
    # what is worth knowing but puts nothing in doubt (`--strict` passes): a stale pilot, which
    # no reported number reads; a platform whose re-simulations here all agree
    notes: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """True when every output is OK (warnings and skipped files do not count)."""
        return all(o.status is Status.OK for o in self.outputs)

    @property
    def complete(self) -> bool:
        """True when nothing was left in doubt: no warning, and every check could run (what
        `mjtrial verify --strict` asks on top of `ok`)."""
        return not self.warnings and not self.unchecked

    @property
    def exit_code(self) -> int:
        return 0 if self.ok else 1

    def __getitem__(self, path: str) -> OutputResult:
        for o in self.outputs:
            if o.path == path:
                return o
        raise KeyError(path)

    def status_of(self, path: str) -> Status:
        return self[path].status

    def with_status(self, status: Status) -> list[str]:
        """Paths of the outputs with ``status``."""
        return [o.path for o in self.outputs if o.status is status]

    def counts(self) -> dict[Status, int]:
        counts = dict.fromkeys(Status, 0)
        for o in self.outputs:
            counts[o.status] += 1
        return counts

    def summary(self) -> str:
        c = self.counts()
        # irreproducible is said only when there is one: a rare verdict, the others always
        shown = [s for s in Status if s is not Status.IRREPRODUCIBLE or c[s]]
        parts = ", ".join(f"{c[s]} {s.value}" for s in shown)
        verdict = "verified" if self.ok else "NOT verified"
        return (
            f"{verdict}: {self.results_dir}: {len(self.outputs)} outputs: {parts} "
            f"({len(self.warnings)} warnings, {len(self.skipped)} skipped)"
        )

    def lines(self) -> list[str]:
        """One line per output, then skipped files, warnings, checks and the summary line."""
        return [
            *(o.line() for o in self.outputs),
            *(s.line() for s in self.skipped),
            *(f"warning  {w}" for w in self.warnings),
            *(f"note     {n}" for n in self.notes),
            *(f"checked  {c}" for c in self.checks),
            self.summary(),
        ]

    def format(self) -> str:
        return "\n".join(self.lines())


@dataclass(frozen=True)
class Current:
    """What the stamps are checked against: the config, code, versions and machine of now."""

    config: Mapping[str, Any]
    code: Mapping[str, Mapping[str, str] | None]  # per stage: `stamping.stage_code`
    versions: Mapping[str, str | None]
    platform: Mapping[str, Any] = field(default_factory=dict)
    task_files: tuple[str, ...] | None = None  # a task named by path: its files, as recorded

    @classmethod
    def of_environment(cls, config: Mapping[str, Any], *, repo_root: Path = REPO_ROOT) -> Current:
        """``config`` with each stage's code as it is now, this environment's library versions,
        this machine's platform fingerprint and the files of the config's task."""
        task, files = config.get("task"), None
        if isinstance(task, str) and task.endswith(".py"):
            try:
                found = task_files(Path(repo_root) / task)
                files = tuple(provenance.repo_relative(p, repo_root) for p in found)
            except (OSError, ValueError):
                files = None
        code: dict[str, Mapping[str, str] | None] = {}
        for stage in STAGES:
            try:
                code[stage] = stage_code(stage)
            except (ImportError, OSError, SyntaxError):
                code[stage] = None
        return cls(
            config=config,
            code=code,
            versions=provenance.library_versions(),
            platform=provenance.platform_fingerprint(),
            task_files=files,
        )


def parse_rule(rule: Any) -> tuple[str, str | None] | None:
    """(stage, qualifier) of a stamp's rule, or None for a rule outside the pipeline.

    ``"rollout:fast"`` -> ``("rollout", "fast")`` (the qualifier of a rollout is its condition),
    ``"states:development"`` -> ``("states", "development")``, ``"analysis"`` ->
    ``("analysis", None)``; ``"replay"`` (an ``mjtrial replay`` recording) -> None.
    """
    if not isinstance(rule, str):
        return None
    stage, sep, qualifier = rule.partition(":")
    if stage not in STAGES or (sep and not qualifier):
        return None
    if stage in CONDITION_STAGES and not qualifier:
        return None
    return stage, qualifier or None


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def _created(stamp: Mapping[str, Any]) -> datetime | None:
    value = stamp.get("created_utc")
    if not isinstance(value, str):
        return None
    try:
        return datetime.strptime(value, "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=timezone.utc)
    except ValueError:
        return None


def _newer(stamp: Mapping[str, Any], than: Mapping[str, Any]) -> bool:
    """True when ``stamp`` was made strictly after ``than`` (False when either time is bad)."""
    a, b = _created(stamp), _created(than)
    return a is not None and b is not None and a > b


def _input_records(stamp: Mapping[str, Any]) -> Iterator[tuple[str, Any]]:
    """(input name, record) for every recorded input; a list input gives one pair per file."""
    inputs = stamp.get("inputs")
    if not isinstance(inputs, Mapping):
        return
    for name, value in inputs.items():
        for record in value if isinstance(value, list) else [value]:
            yield str(name), record


def _valid_record(record: Any) -> bool:
    return (
        isinstance(record, Mapping)
        and isinstance(record.get("path"), str)
        and isinstance(record.get("sha256"), str)
    )


def _short(value: Any, width: int = 40) -> str:
    try:
        text = json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= width else text[: width - 3] + "..."


_ABSENT = object()


def dict_diff(old: Any, new: Any, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ, as ``key: old -> new``."""
    if isinstance(old, Mapping) and isinstance(new, Mapping):
        out: list[str] = []
        for key in sorted(set(old) | set(new), key=str):
            dotted = f"{prefix}.{key}" if prefix else str(key)
            out += dict_diff(old.get(key, _ABSENT), new.get(key, _ABSENT), dotted)
        return out
    if old is _ABSENT:
        return [f"{prefix or '(slice)'}: added {_short(new)}"]
    if new is _ABSENT:
        return [f"{prefix or '(slice)'}: removed"]
    try:
        same = provenance.config_hash(old) == provenance.config_hash(new)
    except (TypeError, ValueError):  # NaN: equal when JSON writes them the same
        same = old == new or json.dumps(old, sort_keys=True) == json.dumps(new, sort_keys=True)
    return [] if same else [f"{prefix or '(slice)'}: {_short(old)} -> {_short(new)}"]


def _names(paths: Iterable[str], prefix: str) -> str:
    """A short list of paths (relative to the results folder), "a, b, c and 4 more"."""
    shown = [p.removeprefix(prefix) for p in paths]
    if len(shown) <= _NAMES_SHOWN:
        return ", ".join(shown)
    return f"{', '.join(shown[:_NAMES_SHOWN])} and {len(shown) - _NAMES_SHOWN} more"


def _rank(rule: Any, path: str) -> tuple[int, str]:
    parsed = parse_rule(rule)
    stage = parsed[0] if parsed else None
    return (_STAGE_ORDER.index(stage) if stage in _STAGE_ORDER else len(_STAGE_ORDER), path)


def _git_key(stamp: Mapping[str, Any]) -> str:
    git = stamp.get("git")
    if not isinstance(git, Mapping) or not git.get("available"):
        return "no git state"
    commit = str(git.get("commit") or "?")[:12]
    diff = git.get("diff_sha256")
    return f"commit {commit}" + (f" + uncommitted diff {str(diff)[:12]}" if diff else " (clean)")


def _grouped(groups: Mapping[str, list[str]], prefix: str) -> str:
    return "; ".join(
        f"{value} ({len(paths)}: {_names(paths, prefix)})"
        for value, paths in sorted(groups.items(), key=lambda kv: (-len(kv[1]), kv[0]))
    )


def _platform_key(platform: Any) -> tuple[str, tuple[str, ...]]:
    platform = platform if isinstance(platform, Mapping) else {}
    flags = platform.get("cpu_flags_fp")
    flags = tuple(sorted(str(f) for f in flags)) if isinstance(flags, list) else ()
    return str(platform.get("cpu_model")), flags


def _variant_mujoco(stamp: Mapping[str, Any]) -> dict[str, str]:
    """{"mujoco": version} for a stamp of a variant that names another MuJoCo, else {}."""
    config_slice = stamp.get("config_slice")
    variant = config_slice.get("variant") if isinstance(config_slice, Mapping) else None
    version = variant.get(VERSION_KEY) if isinstance(variant, Mapping) else None
    return {VERSION_KEY: version} if isinstance(version, str) else {}


# The one command that makes every stamp of a run agree: each output rebuilt here, now.
REBUILD_ALL = "`snakemake -c2 --forceall`"
PLATFORM_WARNINGS = ("platform differs from this machine", "stamps were made on ")


def _consistency_warnings(
    stamps: Mapping[str, Mapping[str, Any]], current: Current, prefix: str
) -> list[str]:
    """Warnings: the stamps of one run disagree (git state, versions, platform), or the
    platform they were made on is not this machine's."""
    warnings: list[str] = []
    if not stamps:
        return warnings
    git: dict[str, list[str]] = defaultdict(list)
    for path, stamp in stamps.items():
        git[_git_key(stamp)].append(path)
    if len(git) > 1:
        warnings.append(
            f"stamps disagree on the git state: {_grouped(git, prefix)}; {REBUILD_ALL} rebuilds "
            "every output at this checkout's commit"
        )

    keys = set()
    for stamp in stamps.values():
        versions = stamp.get("versions")
        keys |= set(versions) if isinstance(versions, Mapping) else set()
    for key in sorted(keys):
        values: dict[str, list[str]] = defaultdict(list)
        for path, stamp in stamps.items():
            versions = stamp.get("versions")
            value = versions.get(key) if isinstance(versions, Mapping) else None
            if key not in _variant_mujoco(stamp):  # a variant's own MuJoCo differs by design
                values[str(value)].append(path)
        if len(values) > 1:
            warnings.append(
                f"stamps disagree on {key}: {_grouped(values, prefix)}; {REBUILD_ALL} rebuilds "
                "every output with this environment's"
            )

    platforms: dict[tuple[str, tuple[str, ...]], list[str]] = defaultdict(list)
    for path, stamp in stamps.items():
        platforms[_platform_key(stamp.get("platform"))].append(path)
    if len(platforms) > 1:
        warnings.append(
            f"stamps were made on {len(platforms)} different platforms (cpu_model, "
            f"cpu_flags_fp): results may not be bit-for-bit consistent with each other; "
            f"{REBUILD_ALL} on one machine rebuilds them all there"
        )
    here_model, here_flags = _platform_key(current.platform)
    for (model, flags), paths in sorted(platforms.items()):
        if (model, flags) == (here_model, here_flags):
            continue
        what = []
        if model != here_model:
            what.append(f"cpu_model {model!r} (here {here_model!r})")
        if flags != here_flags:
            gained = sorted(set(here_flags) - set(flags))
            lost = sorted(set(flags) - set(here_flags))
            change = ", ".join([*(f"+{f}" for f in gained), *(f"-{f}" for f in lost)])
            what.append(f"cpu_flags_fp differ here: {change}")
        warnings.append(
            f"platform differs from this machine: {'; '.join(what)} in "
            f"{len(paths)} stamps ({_names(sorted(paths), prefix)}): a rebuild here may not "
            f"reproduce them bit for bit; verify's re-simulations say whether they do (a note "
            f"when all agree), {REBUILD_ALL} rebuilds them here"
        )
    return warnings


def _topological(upstream: Mapping[str, set[str]], nodes: Iterable[str]) -> list[str]:
    """``nodes`` ordered so that each comes after its upstream nodes (cycles: any order)."""
    members = set(nodes)
    order: list[str] = []
    seen: set[str] = set()

    def visit(node: str) -> None:
        if node in seen:
            return
        seen.add(node)
        for source in sorted(upstream.get(node, ())):
            if source in members:
                visit(source)
        order.append(node)

    for node in sorted(members):
        visit(node)
    return order


# --------------------------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------------------------


def check_stamps(
    stamps: Mapping[str, Mapping[str, Any]],
    *,
    current: Current,
    current_sha256: Callable[[str], str | None],
    outputs_prefix: str,
    unreadable: Mapping[str, str] | None = None,
    manifest: Mapping[str, Any] | None = None,
    manifest_path: str | None = None,
    seal_paths: Iterable[str] = (),
    expected_paths: Iterable[str] = (),
    recomputed_differs: Mapping[str, str] | None = None,
    outdated: Mapping[str, str] | None = None,
    development_prefix: str | None = None,
    sources: Iterable[str] = (),
    irreproducible: Mapping[str, str] | None = None,
) -> VerifyReport:
    """Judge every output from stamps already read; no file access except ``current_sha256``.

    ``stamps`` maps each stamped file found (repository-relative POSIX path) to its stamp;
    ``unreadable`` maps files found without a readable stamp to why.  ``current_sha256(path)``
    gives the sha256 of a repository-relative path now, None when it does not exist.  Recorded
    inputs under ``outputs_prefix`` (e.g. ``"results/research_mode/"``) are outputs; the others
    (the model) are source files.  ``manifest`` is the parsed ``manifest.json`` (its ``stamps``
    name the outputs expected besides ``manifest_path`` itself). ``seal_paths`` are the seals
    expected, whose stamps record the sha256 of every output, reports and figures included: an
    edit to any of them is seen there. ``expected_paths`` are further outputs that must be
    there (a study's summary beside its report). ``recomputed_differs`` maps outputs that
    differ from their recomputation (:mod:`mjtrial.verify.recompute`) to why: tampered.
    ``irreproducible`` maps outputs that differ from a re-simulation which itself does not
    reproduce (two disagree) to why: irreproducible, which fails as tampered does.
    ``outdated`` maps outputs that miss something built after them (a crate that does not
    cover a study sealed since) to why: stale. Outputs under ``development_prefix`` (the
    development states and the pilot) are read by no reported number: one that is stale or
    missing (a pilot of an earlier configuration) is a note, not a failure, and an output
    outside it that records an input under it is tampered. ``sources`` are files under
    ``outputs_prefix`` that no job writes (the registered design): inputs, as the model is.
    """
    sources = set(sources)
    unreadable = dict(unreadable or {})
    prefix = outputs_prefix.rstrip("/") + "/"
    shas: dict[str, str | None] = {}

    def sha(path: str) -> str | None:
        if path not in shas:
            shas[path] = current_sha256(path)
        return shas[path]

    pipeline_stamps: dict[str, Mapping[str, Any]] = {}
    parsed: dict[str, tuple[str, str | None]] = {}
    skipped: list[Skipped] = []
    for path, stamp in stamps.items():
        rule = parse_rule(stamp.get("rule")) if isinstance(stamp, Mapping) else None
        if rule is None:
            shown = stamp.get("rule") if isinstance(stamp, Mapping) else None
            skipped.append(Skipped(path, f"rule {shown!r} is not part of the pipeline"))
            continue
        pipeline_stamps[path] = stamp
        parsed[path] = rule

    found = set(pipeline_stamps) | set(unreadable)
    expected: set[str] = set()
    manifest_rules: dict[str, Any] = {}
    expected.update(p for p in (manifest_path, *seal_paths, *expected_paths) if p is not None)
    recorded = manifest.get("stamps") if isinstance(manifest, Mapping) else None
    if isinstance(recorded, Mapping):
        for path, stamp in recorded.items():
            expected.add(str(path))
            manifest_rules[str(path)] = stamp.get("rule") if isinstance(stamp, Mapping) else None

    stale: dict[str, list[str]] = defaultdict(list)
    tampered: dict[str, list[str]] = defaultdict(list)
    upstream: dict[str, set[str]] = defaultdict(set)
    recorders: dict[str, list[str]] = defaultdict(list)  # output -> stamps whose sha differs
    for path, why in unreadable.items():
        tampered[path].append(f"no readable stamp ({why})")
    for path, why in (recomputed_differs or {}).items():
        tampered[path].append(why)
    unrepeatable: dict[str, list[str]] = defaultdict(list)
    for path, why in (irreproducible or {}).items():
        unrepeatable[path].append(why)
    for path, why in (outdated or {}).items():
        stale[path].append(why)

    model_path = current.config.get("model")
    development = development_prefix.rstrip("/") + "/" if development_prefix else None
    for path, stamp in pipeline_stamps.items():
        stage, qualifier = parsed[path]
        # "rollout:<variant>/<condition>#<shard>": the slice is the (variant's) condition's
        condition = qualifier.partition("#")[0] if stage in CONDITION_STAGES else None
        rule = stamp["rule"]

        # The stamp itself: its recorded slice must hash to its recorded slice hash.
        recorded_hash = stamp.get("config_slice_sha256")
        try:
            consistent = provenance.config_hash(stamp.get("config_slice")) == recorded_hash
        except (TypeError, ValueError):
            consistent = False
        if not consistent:
            tampered[path].append("config_slice_sha256 does not match the stamp's config_slice")

        # Config slice.
        try:
            now = config_slice(stage, current.config, condition=condition)
        except (KeyError, TypeError) as err:
            gone = f"condition {condition!r} is not in the config" if condition else repr(err)
            stale[path].append(f"config slice changed: {rule}: {gone}")
        else:
            if provenance.config_hash(now) != recorded_hash:
                diff = dict_diff(stamp.get("config_slice"), now) if consistent else []
                more = f" and {len(diff) - 3} more" if len(diff) > 3 else ""
                detail = f" ({', '.join(diff[:3])}{more})" if diff else ""
                stale[path].append(f"config slice changed: {rule}{detail}")

        # Code: the stage's script and every package module it imports, each by its sha256.
        extra = stamp.get("extra")
        code = extra.get("code") if isinstance(extra, Mapping) else None
        code_now = current.code.get(stage)
        if not isinstance(code, Mapping):
            stale[path].append(f"no code record in its stamp (stage {stage})")
        elif code_now is None:
            stale[path].append(f"code of stage {stage} cannot be read now")
        elif changed := codehash.changed_code(code, code_now):
            stale[path].append(f"code changed: {_names(changed, '')}")

        # Library versions against this environment (or the MuJoCo its variant names).
        versions = stamp.get("versions")
        versions = versions if isinstance(versions, Mapping) else {}
        wanted = {**current.versions, **_variant_mujoco(stamp)}
        changed = [
            f"{key} {versions.get(key)} -> {wanted.get(key)}"
            for key in sorted(set(versions) | set(wanted))
            if versions.get(key) != wanted.get(key)
        ]
        if changed:
            stale[path].append(f"versions changed: {', '.join(changed)}")

        # Inputs.
        for name, record in _input_records(stamp):
            if not _valid_record(record):
                tampered[path].append(f"malformed input record {name!r} in its stamp")
                continue
            source, recorded_sha = record["path"], record["sha256"]
            if development and source.startswith(development) and not path.startswith(development):
                tampered[path].append(
                    f"reads a development output, {source.removeprefix(prefix)}: the evaluation "
                    "never does"
                )
            if source.startswith(prefix) and source not in sources:
                expected.add(source)
                upstream[path].add(source)
                now_sha = sha(source)
                if now_sha is None or now_sha == recorded_sha:
                    continue  # a missing input is reported through propagation
                source_stamp = pipeline_stamps.get(source) or stamps.get(source)
                if isinstance(source_stamp, Mapping) and _newer(source_stamp, stamp):
                    stale[path].append(f"input rebuilt after it: {source.removeprefix(prefix)}")
                else:
                    recorders[source].append(path)
                continue
            label = "model" if name.startswith("model") or source == model_path else "input"
            now_sha = sha(source)
            if now_sha is None:
                stale[path].append(f"{label} missing: {source}")
            elif now_sha != recorded_sha:
                stale[path].append(f"{label} changed: {source}")
            if name == "model" and isinstance(model_path, str) and source != model_path:
                stale[path].append(f"model changed: {source} -> {model_path}")
        # A file added to the task's folder (an edited or removed one is seen above).
        task = {r["path"] for n, r in _input_records(stamp) if n == "task" and _valid_record(r)}
        if task and current.task_files is not None:
            if added := sorted(set(current.task_files) - task):
                stale[path].append(f"task file added: {_names(added, '')}")

    # The manifest's own record of the model.
    if manifest_path in pipeline_stamps and isinstance(manifest, Mapping):
        model = manifest.get("model")
        if isinstance(model, Mapping) and isinstance(model.get("path"), str):
            folder = posixpath.dirname(model["path"])
            files = model.get("files")
            if not isinstance(files, Mapping):
                files = {posixpath.basename(model["path"]): model.get("sha256")}
            for name, recorded_sha in files.items():
                source = posixpath.join(folder, name)
                now_sha = sha(source)
                reason = f"model changed: {source}"
                if now_sha is not None and now_sha != recorded_sha:
                    if reason not in stale[manifest_path]:
                        stale[manifest_path].append(reason)

    for source, by in recorders.items():
        by = sorted(set(by), key=lambda p: _rank(pipeline_stamps[p].get("rule"), p))
        tampered[source].append(
            f"sha256 recorded by {_names(by, prefix)} does not match the file "
            f"(its stamp is not newer than {'that record' if len(by) == 1 else 'those records'})"
        )

    # A file the pipeline is expected to hold whose stamp names no pipeline rule was re-stamped.
    for entry in list(skipped):
        if entry.path in expected:
            skipped.remove(entry)
            found.add(entry.path)
            tampered[entry.path].append(f"its stamp's {entry.reason}")

    missing = expected - found
    status: dict[str, Status] = dict.fromkeys(missing, Status.MISSING)

    def rank(p: str) -> tuple[int, str]:
        stamp = pipeline_stamps.get(p)
        return _rank(stamp.get("rule") if stamp else manifest_rules.get(p), p)

    for path in _topological(upstream, found):
        if path in pipeline_stamps:
            bad: dict[Status, list[str]] = defaultdict(list)
            for source in sorted(upstream.get(path, ()), key=rank):
                source_status = status.get(source)
                if source_status is not None and source_status is not Status.OK:
                    bad[source_status].append(source)
            for st in (Status.TAMPERED, Status.IRREPRODUCIBLE, Status.MISSING, Status.STALE):
                if bad[st]:
                    stale[path].append(f"input {st.value}: {_names(bad[st], prefix)}")
        if tampered.get(path):
            status[path] = Status.TAMPERED
        elif unrepeatable.get(path):
            status[path] = Status.IRREPRODUCIBLE
        elif stale.get(path):
            status[path] = Status.STALE
        else:
            status[path] = Status.OK

    results, advisory = [], []
    for path, st in status.items():
        rule = pipeline_stamps[path].get("rule") if path in pipeline_stamps else None
        reasons = (
            ()
            if st is Status.OK
            else (*tampered.get(path, ()), *unrepeatable.get(path, ()), *stale.get(path, ()))
        )
        result = OutputResult(path, st, tuple(reasons), rule)
        if development and path.startswith(development) and st in (Status.STALE, Status.MISSING):
            advisory.append(
                f"development output {result.line()} (no reported number reads it; "
                "`snakemake -c2 pilot` or `dev` rebuilds it)"
            )
            continue
        results.append(result)
    results.sort(key=lambda r: rank(r.path))
    skipped.sort(key=lambda s: s.path)
    return VerifyReport(
        results_dir=prefix.rstrip("/"),
        outputs=tuple(results),
        warnings=tuple(_consistency_warnings(pipeline_stamps, current, prefix)),
        skipped=tuple(skipped),
        notes=tuple(sorted(advisory)),
    )
