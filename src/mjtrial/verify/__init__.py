"""Check a results folder against its stamps: is every output still what the pipeline would build?

Every output carries a provenance stamp (:mod:`mjtrial.provenance`) recording the sha256 of the
files it was made from, its config slice's hash and the hash of the package code its stage runs.
:func:`verify_results` reads every stamp in a results folder and checks that chain against the
files, the config, the model and the code as they are now.  Each output gets one
:class:`Status`:

* ``OK``: its inputs, config slice, model, code and library versions are unchanged.
* ``STALE``: something it was built from changed since (a config value, the model, a package
  module, a library version, or an input that was legitimately rebuilt after it), or one of its
  inputs is itself stale, tampered or missing.  A rebuild fixes it.
* ``TAMPERED``: its bytes no longer match the sha256 that a later output recorded for it, while
  its own stamp says nothing rebuilt it after that record; or it has no readable stamp.
* ``MISSING``: the manifest (or another output's stamp) names it, but it is not there.

An output's own sha256 can only be recorded by the outputs built from it; the last rule, the
seal (``seal.json``), is built from every output, so the report and the figures are checked
too. Only the seal itself is checked for a readable, current stamp alone.

:func:`check_stamps` holds all the logic on stamps already read; :func:`verify_results` does the
reading and hashing.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from mjtrial import provenance
from mjtrial.config import check_config, merge_config, read_config_file
from mjtrial.crate.check import covered_seals
from mjtrial.design.conditions import all_conditions, variant_names
from mjtrial.files.layout import FIGURES, STUDIES, STUDY_FIGURES, Layout
from mjtrial.provenance.recording_folders import folder_problem
from mjtrial.stages.look import shards_run
from mjtrial.stages.states import piloted_overlap
from mjtrial.verify.chain import (
    PLATFORM_WARNINGS,
    STAMPED_SUFFIXES,
    Current,
    OutputResult,
    Skipped,
    Status,
    VerifyReport,
    check_stamps,
    dict_diff,
    parse_rule,
)
from mjtrial.verify.contracts import contract_change
from mjtrial.verify.folder import placed_as_recorded, recorded_as
from mjtrial.verify.recompute import DEFAULT_RESIMULATE, recompute
from mjtrial.verify.registration import check_deviations_kept, check_registration

__all__ = [
    "STAMPED_SUFFIXES",
    "DEFAULT_RESIMULATE",
    "Current",
    "OutputResult",
    "Skipped",
    "Status",
    "VerifyReport",
    "check_stamps",
    "load_checked_config",
    "parse_rule",
    "verify_results",
]


# --------------------------------------------------------------------------------------------
# Reading a results folder
# --------------------------------------------------------------------------------------------


def load_checked_config(config_path: Path, *, repo_root: Path) -> dict[str, Any]:
    """Read and check the config as the Snakefile does, the model resolved in ``repo_root``."""
    config = read_config_file(config_path)
    check_config(config, source=str(config_path), repo_root=repo_root)
    return config


def _relative(path: Path, root: Path) -> str:
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return path.as_posix()


def _stamped_files(results_dir: Path) -> list[Path]:
    """Outputs under ``results_dir`` that should carry a stamp (hidden temp files excluded).

    A folder written as one output (a shard's recordings, the crate's copy of the sources:
    `provenance.is_folder_output`) is one output, not its files.
    """
    if not results_dir.is_dir():
        return []
    visible = [
        p
        for p in results_dir.rglob("*")
        if not any(part.startswith(".") for part in p.relative_to(results_dir).parts)
    ]
    folders = {p for p in visible if provenance.is_folder_output(p)}
    return sorted(
        p
        for p in visible
        if p in folders
        or (
            not p.is_dir()  # a FIFO too: read_stamp refuses it, and verify says so
            and p.exists()
            and p.suffix.lower() in STAMPED_SUFFIXES
            and not any(parent in folders for parent in p.parents)
        )
    )


def _why_unreadable(err: BaseException, path: Path) -> str:
    if isinstance(err, provenance.MissingStampError):
        return "no stamp"
    text = " ".join(str(err).split()).replace(str(path), path.name)
    text = text.removeprefix(f"{path.name}: ")
    return f"{type(err).__name__}: {text}"[:120]


def _rollout_outputs(layout: Layout, config: Mapping[str, Any]) -> set[Path]:
    """Every rollout output the configuration names (the nominal model's conditions, sweep
    included, and each variant's)."""
    # the shards that ran: a stopping rule's up to the look that stopped (the others are an
    # earlier run's)
    shards = shards_run(layout, config)
    recorded = config["recording"]["episodes"] != "none"
    out = set(layout.rollout_outputs(list(all_conditions(config)), shards, recorded=recorded))
    for variant in variant_names(config):
        out |= set(
            layout.rollout_outputs(
                list(config["conditions"]), shards, recorded=recorded, variant=variant
            )
        )
    return out


def _is_rollout_output(layout: Layout, path: Path) -> bool:
    """Whether `path` lies where rollouts go (`rollouts/`, `variants/*/rollouts/`)."""
    rel = path.relative_to(layout.root).parts
    return rel[:1] == ("rollouts",) or (rel[:1] == ("variants",) and rel[2:3] == ("rollouts",))


def _is_old_figure(layout: Layout, path: Path) -> bool:
    """Whether `path` is a figure no current report or study draws (one renamed since)."""
    return path.parent == layout.figures_dir and path.stem not in {
        *FIGURES,
        *STUDY_FIGURES.values(),
    }


def _seals(layout: Layout) -> list[Path]:
    """The seals a results folder must hold: the built-in experiment's, and each study's
    that has been run."""
    return [layout.seal] + [layout.study_seal(s) for s in _studies_run(layout)]


def _studies_run(layout: Layout) -> list[str]:
    """The studies any of whose outputs (summary, report, seal) is there: then all must be."""
    return [
        s
        for s in STUDIES
        if any(
            p.exists()
            for p in (layout.study_summary(s), layout.study_report(s), layout.study_seal(s))
        )
    ]


def _crate_outdated(layout: Layout, stamps: Mapping[str, Any], repo_root: Path) -> dict[str, str]:
    """The crate, when a seal is there that it does not cover (a study sealed after it)."""
    crate = _relative(layout.crate, repo_root)
    stamp = stamps.get(crate)
    if not isinstance(stamp, Mapping):
        return {}
    covered = set(covered_seals(stamp))
    missed = [_relative(s, repo_root) for s in _seals(layout) if s.exists()]
    missed = [s for s in missed if s not in covered]
    if not missed:
        return {}
    names = ", ".join(Path(s).name for s in missed)
    return {crate: f"it does not cover {names}, sealed after it"}


def _contracts_changed(stamps: Mapping[str, Any], *, repo_root: Path) -> dict[str, str]:
    """Outputs whose policy file now reads another contract than the one its stamp records
    (`verify.contracts.contract_change`), each with the reason naming both contracts."""
    changed: dict[str, str] = {}
    for path, stamp in stamps.items():
        inputs = stamp.get("inputs") if isinstance(stamp, Mapping) else None
        for name, records in inputs.items() if isinstance(inputs, Mapping) else ():
            if name == "policy" or str(name).startswith("policy:"):
                if isinstance(records, list) and (
                    why := contract_change(records, repo_root=repo_root)
                ):
                    changed[path] = why
    return changed


def _recorded_command(manifest: Mapping[str, Any] | None) -> str:
    """The command the manifest says the run was (not derived from any input: not checked)."""
    rerun = manifest.get("rerun") if isinstance(manifest, Mapping) else None
    command = rerun.get("command") if isinstance(rerun, Mapping) else None
    return command if isinstance(command, str) else "snakemake -c2"


def _config_of_the_run(
    config_path: Path, manifest: Mapping[str, Any] | None, *, repo_root: Path
) -> tuple[dict[str, Any], dict[str, Any], list[str]]:
    """The configuration the results are checked against, the command-line values in it, and
    a warning when those make it differ from the file.

    A run given `--config` or `--configfile` values records them in its manifest
    (`rerun.command_line`); they are applied on top of the file, as the run did. Without
    them, the file alone: an edit since the run makes what it touches stale.
    """
    file_config = load_checked_config(config_path, repo_root=repo_root)
    rerun = manifest.get("rerun") if isinstance(manifest, Mapping) else None
    command_line = rerun.get("command_line") if isinstance(rerun, Mapping) else None
    if not isinstance(command_line, dict) or not command_line:
        return file_config, {}, []
    config = merge_config(file_config, command_line)
    check_config(
        config,
        source=f"{config_path} with the command-line values recorded in the manifest",
        repo_root=repo_root,
        overrides=command_line,
    )
    differ = dict_diff(file_config, config)
    more = f" and {len(differ) - 3} more" if len(differ) > 3 else ""
    warning = (
        f"the run was given config values on the command line ({rerun.get('command')}); "
        f"checked against {config_path.name} with them, as the run used it"
    )
    if differ:
        warning += f"; they differ from the file: {', '.join(differ[:3])}{more}"
    return config, command_line, [warning]


def _piloted(
    layout: Layout, outputs: tuple[OutputResult, ...], *, repo_root: Path
) -> tuple[OutputResult, ...]:
    """The outputs, the evaluation states not OK when any of them is a state a pilot of this
    experiment tuned on (`stages.states.piloted_overlap`): the states stage refuses them."""
    states = _relative(layout.states, repo_root)
    try:
        reason = piloted_overlap(pq.read_table(layout.states), development=layout.development)
    except (OSError, ValueError, KeyError):
        return outputs  # unreadable states or pilot: the stamps' checks say so
    if reason is None:
        return outputs
    reason = reason.replace(str(layout.root), _relative(layout.root, repo_root))
    return tuple(
        dataclasses.replace(
            o,
            status=Status.STALE if o.status is Status.OK else o.status,
            reasons=(*o.reasons, reason),
        )
        if o.path == states
        else o
        for o in outputs
    )


def verify_results(
    results_dir: Path,
    *,
    config_path: Path,
    repo_root: Path,
    resimulate: int | None = None,
    seed: int | None = None,
) -> VerifyReport:
    """Read every stamp under ``results_dir`` and check the chain (see :func:`check_stamps`),
    then recompute what the stamps judge current and re-simulate ``resimulate`` episodes per
    shard (:mod:`mjtrial.verify.recompute`; None: every one when that fits the time budget of
    :mod:`mjtrial.verify.coverage`, else a sample), drawn with ``seed`` (None: a fresh one,
    which the report's check line prints): an output that differs is tampered.

    ``repo_root`` is the folder Snakemake ran in: stamps record paths relative to it, and the
    model path in the config is resolved in it.  ``results_dir`` must lie inside it.  Raises
    ``mjtrial.config.ConfigError`` for a config the pipeline would refuse.
    """
    repo_root = Path(repo_root).resolve()
    # Not resolved: a results folder may be a symlink to another disk, and stamps record the
    # path through the link.
    results_dir = Path(os.path.normpath(Path(results_dir).absolute()))
    if not results_dir.is_relative_to(repo_root) and results_dir.resolve().is_relative_to(
        repo_root
    ):
        results_dir = results_dir.resolve()  # the repository reached through a symlink
    recorded = recorded_as(results_dir, repo_root=repo_root)
    if recorded is not None:
        return _verify_copy(
            results_dir,
            recorded=recorded,
            config_path=Path(config_path),
            repo_root=repo_root,
            resimulate=resimulate,
            seed=seed,
        )
    if results_dir != repo_root and repo_root not in results_dir.parents:
        raise ValueError(
            f"{results_dir}: not inside the repository root {repo_root}; stamps record paths "
            "relative to it (pass --repo-root)"
        )
    layout = Layout(results_dir)
    manifest_file = layout.manifest
    manifest: dict[str, Any] | None = None
    try:
        loaded = json.loads(provenance.read_output_text(manifest_file))
        manifest = loaded if isinstance(loaded, dict) else None
    except (OSError, ValueError):
        manifest = None
    config, command_line, config_warnings = _config_of_the_run(
        Path(config_path), manifest, repo_root=repo_root
    )
    current = Current.of_environment(config, repo_root=repo_root)

    ours = _rollout_outputs(layout, config)
    # recording.episodes none gathers no failures: those of an earlier run are not this one's
    unrecorded = (
        {layout.failures, layout.failures_table}
        if config["recording"]["episodes"] == "none"
        else set()
    )
    stamps: dict[str, dict[str, Any]] = {}
    unreadable: dict[str, str] = {}
    leftovers: list[Skipped] = []
    damaged: dict[str, str] = {}  # a folder of recordings without a file its record names
    for file in _stamped_files(results_dir):
        rel = _relative(file, repo_root)
        if (_is_rollout_output(layout, file) and file not in ours) or file in unrecorded:
            leftovers.append(
                Skipped(rel, "left by an earlier configuration; not one of its outputs")
            )
            continue
        if file in (layout.registration, layout.deviations):
            continue  # no job's outputs: checked on their own (check_registration)
        if _is_old_figure(layout, file):
            leftovers.append(Skipped(rel, "a figure no current report draws (an earlier layout)"))
            continue
        if provenance.is_recording_folder(file) and (problem := folder_problem(file)):
            damaged[rel] = problem.replace(str(file), rel)
        try:
            stamps[rel] = provenance.read_stamp(file)
        except FileNotFoundError:
            continue  # removed while we looked: missing if anything expects it
        except Exception as err:  # noqa: BLE001 - any failure to read it is "no readable stamp"
            if file.exists():
                unreadable[rel] = _why_unreadable(err, file)

    @functools.cache
    def current_sha256(rel: str) -> str | None:
        p = Path(rel)
        p = p if p.is_absolute() else repo_root / p
        try:
            return provenance.file_sha256(p) if p.is_file() or p.is_dir() else None
        except OSError:
            return None

    def check(
        differs: Mapping[str, str] | None = None, irreproducible: Mapping[str, str] | None = None
    ) -> VerifyReport:
        return check_stamps(
            stamps,
            current=current,
            current_sha256=current_sha256,
            outputs_prefix=_relative(results_dir, repo_root),
            unreadable=unreadable,
            manifest=manifest,
            manifest_path=_relative(manifest_file, repo_root),
            seal_paths=[_relative(p, repo_root) for p in _seals(layout)],
            expected_paths=[
                _relative(p, repo_root)
                for p in [
                    layout.crate,
                    layout.source,
                    *(
                        p
                        for s in _studies_run(layout)
                        for p in (layout.study_summary(s), layout.study_report(s))
                    ),
                ]
            ],
            recomputed_differs={
                p: "; ".join(w for w in (damaged.get(p), (differs or {}).get(p)) if w)
                for p in {*damaged, *(differs or {})}
            },
            irreproducible=irreproducible,
            outdated={
                **_crate_outdated(layout, stamps, repo_root),
                **_contracts_changed(stamps, repo_root=repo_root),
            },
            development_prefix=_relative(layout.development.root, repo_root),
            sources=[_relative(layout.registration, repo_root)],
        )

    report = check()
    found = recompute(
        layout,
        config,
        repo_root=repo_root,
        current=report.with_status(Status.OK),
        resimulate=resimulate,
        seed=seed,
        command_line=command_line,
        command=_recorded_command(manifest),
        # as the Snakefile records it: relative to the repository, even from outside it
        config_file=provenance.path_in_repo(config_path, repo_root)
        or os.path.relpath(config_path, repo_root),
        stamps=stamps,
    )
    if found.differs or found.irreproducible:
        report = check(found.differs, found.irreproducible)
    # Another CPU is a doubt until re-simulation here settles it: when every episode verify
    # re-simulated agrees bit for bit, it is a note.
    settled = found.resimulated > 0 and not found.differs
    platform = [w for w in report.warnings if w.startswith(PLATFORM_WARNINGS)] if settled else []
    agree = f"; the {found.resimulated} episodes re-simulated here all agree bit for bit"
    registered = check_registration(
        layout, config, path=_relative(layout.registration, repo_root), repo_root=repo_root
    )
    kept = check_deviations_kept(
        layout, path=_relative(layout.deviations, repo_root), repo_root=repo_root
    )
    return dataclasses.replace(
        report,
        outputs=(
            *_piloted(layout, report.outputs, repo_root=repo_root),
            *([registered] if registered else []),
            *([kept] if kept else []),
        ),
        skipped=(*report.skipped, *leftovers),
        warnings=(*config_warnings, *(w for w in report.warnings if w not in platform)),
        notes=(*report.notes, *(w + agree for w in platform)),
        checks=(found.line(),),
        unchecked=tuple(
            f"{', '.join(conditions)} not re-simulated ({why})"
            for why, conditions in found.elsewhere.items()
        ),
    )


def _verify_copy(
    results_dir: Path,
    *,
    recorded: str,
    config_path: Path,
    repo_root: Path,
    resimulate: int | None,
    seed: int | None,
) -> VerifyReport:
    """A copy of a run (`verify.folder.recorded_as`) checked as what it is: placed where its
    seal says the run was recorded, in a view of this checkout (`placed_as_recorded`), its files
    against its seal and stamps and its recomputations and re-simulations with this checkout's
    code, config, model and task; a note says so, and what needs the original place."""
    shown = provenance.path_in_repo(results_dir, repo_root) or results_dir.as_posix()
    with placed_as_recorded(results_dir, recorded=recorded, repo_root=repo_root) as view:
        in_view = provenance.path_in_repo(config_path, repo_root)
        report = verify_results(
            view / recorded,
            config_path=view / in_view if in_view else config_path,
            repo_root=view,
            resimulate=resimulate,
            seed=seed,
        )
    note = (
        f"{shown} is a copy of the run recorded as {recorded}: checked as it (its files against "
        "its seal and stamps, its recomputations and re-simulations with this checkout's code, "
        f"config, model and task); rebuilding or updating it with snakemake needs it at "
        f"{recorded}"
    )
    return dataclasses.replace(report, results_dir=shown, notes=(note, *report.notes))
