"""Recompute, do not trust the seal: what `mjtrial verify` checks beyond the stamps.

A stamp or a seal records what a file was when it was written, not that it is right: a
forged `summary.json` restamped, or a report edited with its seal deleted, passes every check
on stamps. So verify also rebuilds, in memory, every output that is cheap to rebuild from its
own inputs (the states, each condition's table from its shards, the analysis, the manifest,
the report's text, the studies' summaries and reports) and compares; compares every recorded
episode's outcome and measures (its recording's `episode` property) with its table row; and
re-simulates a sample of episodes of every shard (`resimulate` per shard), each episode alone,
against its table (a variant on another MuJoCo version in that version's environment,
`mjtrial.sim.resimulation`). The sample is drawn from a seed chosen at verify time (printed,
`--seed` repeats it): a forger who can read the code cannot know which rows it will be, and an
episode whose result depends on its batch is not re-confirmed in the batch that made it. By
induction a forged link anywhere in the chain is named: each output is what its inputs give,
and the roots (states, episodes) are what the seeds and the simulator give.

Only outputs the stamps judge current are recomputed: for a stale one (a config value, the
code or the model changed) a difference is expected, and the rebuild fixes it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import provenance
from mjtrial.config import pilot_states
from mjtrial.crate.check import crate_differences
from mjtrial.design.conditions import (
    all_conditions,
    sensitivity_conditions,
    sweep_conditions,
    variant_names,
)
from mjtrial.files.layout import (
    CONFIG_FILE,
    NOMINAL,
    STUDIES,
    Layout,
    evaluation_shard_size,
    shard_ids,
    shard_range,
)
from mjtrial.recording import list_recordings
from mjtrial.report import report_text
from mjtrial.report.traces import record_difference
from mjtrial.sim.resimulation import in_environment, resimulated_outcome
from mjtrial.sim.simenv import env_python, lock_path, variant_version, version_recordings
from mjtrial.stages.analysis import REGISTRATION_INPUT, summarize_tables
from mjtrial.stages.look import look_record, shards_run
from mjtrial.stages.manifest import manifest_record
from mjtrial.stages.pilot import summarize_pilot
from mjtrial.stages.rollout import nominal_episode
from mjtrial.stages.stamping import config_slice
from mjtrial.stages.states import draw_states
from mjtrial.stages.studies import dose_response_summary, sensitivity_summary, study_report_text
from mjtrial.task import NotAFunctionError
from mjtrial.verify.coverage import DEFAULT_RESIMULATE, coverage
from mjtrial.verify.differences import SHOWN as _SHOWN
from mjtrial.verify.differences import (
    columns,
    json_difference,
    markdown_difference,
    not_reproduced,
    recomputed_difference,
    table_difference,
)
from mjtrial.verify.sample import Recomputation, _platform_note, fresh_seed, sample_ids

__all__ = ["DEFAULT_RESIMULATE", "Recomputation", "recompute"]


# --------------------------------------------------------------------------------------------
# The recomputation
# --------------------------------------------------------------------------------------------


class _Checker:
    """Runs each check whose outputs the stamps judged current, recording differences."""

    def __init__(
        self,
        layout: Layout,
        config: Mapping[str, Any],
        repo_root: Path,
        current: Iterable[str],
        command_line: Mapping[str, Any],
        command: str,
    ) -> None:
        self.layout, self.config, self.repo_root = layout, config, repo_root
        self.command_line, self.command = command_line, command
        self.current = set(current)
        self.model_file = repo_root / config["model"]
        self.found = Recomputation()
        self.config_file = CONFIG_FILE
        self.stamps: Mapping[str, Mapping[str, Any]] = {}  # the stamps verify read

    @functools.cached_property
    def installed_mujoco(self) -> str | None:
        """This MuJoCo's version, from its installed metadata as a stamp records it: read once
        per verify, not once per condition and shard."""
        return provenance.library_versions()["mujoco"]

    def rel(self, path: Path) -> str:
        return Path(path).relative_to(self.repo_root).as_posix()

    def is_current(self, *paths: Path) -> bool:
        return all(self.rel(p) in self.current for p in paths)

    def check(self, path: Path, difference: Callable[[], str | None]) -> None:
        if not self.is_current(path):
            return
        self.found.recomputed += 1
        try:
            why = difference()
        except NotAFunctionError as err:  # the task's code, not the file: irreproducible
            self.found.irreproducible[self.rel(path)] = f"cannot be recomputed: {err}"
            return
        except Exception as err:  # noqa: BLE001 - an output that cannot be read back is named
            why = f"cannot be recomputed ({type(err).__name__}: {' '.join(str(err).split())[:100]})"
        if why:
            self.add(path, f"differs from its recomputation: {why}")

    def add(self, path: Path, why: str) -> None:
        """Record why an output differs (after what an earlier check found in it)."""
        rel = self.rel(path)
        self.found.differs[rel] = (
            f"{self.found.differs[rel]}; {why}" if rel in self.found.differs else why
        )

    # -- the checks --------------------------------------------------------------------------

    def states(self) -> None:
        states = config_slice("states", self.config)
        drawn = {}

        def difference(path: Path, development: bool) -> str | None:
            if not drawn:
                drawn["tables"] = draw_states(states, repo_root=self.repo_root)
            table = drawn["tables"][1 if development else 0]
            expected = {c: table.column(c).to_numpy() for c in table.column_names}
            return table_difference(pq.read_table(path), expected)

        self.check(self.layout.states, lambda: difference(self.layout.states, False))
        self.check(
            self.layout.development_states,
            lambda: difference(self.layout.development_states, True),
        )

    def conditions(self) -> Iterable[tuple[str, str]]:
        """(variant, condition) of every rollout the config names."""
        for c in all_conditions(self.config):
            yield NOMINAL, c
        for v in variant_names(self.config):
            for c in self.config["conditions"]:
                yield v, c

    def rollouts(
        self,
        resimulate: int,
        conditions: Iterable[tuple[str, str]] | None = None,
        recorded: str | None = None,
        n: int | None = None,
    ) -> None:
        """Each condition's table against its shards, its nominal episode, its recordings and
        a re-simulated sample of each shard (the conditions, recordings and states of the
        config, unless given: the pilot's are the design's conditions on its first `pilot.n`
        development states, recorded nowhere)."""
        # the evaluation's shards that ran (a stopping rule's, up to the look that stopped), or
        # the pilot's (`n` given) in shards of rollout.shard_size
        size = self.config["rollout"]["shard_size"] if n else evaluation_shard_size(self.config)
        shards = shard_ids(n, size) if n else shards_run(self.layout, self.config)
        n = n or self.config["states"]["n"]
        recorded = recorded or self.config["recording"]["episodes"]
        for variant, condition in self.conditions() if conditions is None else conditions:
            qualified = condition if variant == NOMINAL else f"{variant}/{condition}"
            slice_ = config_slice("rollout", self.config, condition=qualified)
            tables = [self.layout.shard_table(condition, s, variant) for s in shards]
            gathered = self.layout.rollout_table(condition, variant)
            if self.is_current(*tables):

                def concatenated(
                    tables: list[Path] = tables, gathered: Path = gathered
                ) -> str | None:
                    parts = [pq.read_table(p) for p in tables]
                    expected = {
                        c: np.concatenate(
                            [t.column(c).to_numpy(zero_copy_only=False) for t in parts]
                        )
                        for c in parts[0].column_names
                    }
                    return table_difference(
                        pq.read_table(gathered), expected, what="rows of its shards"
                    )

                self.check(gathered, concatenated)
            nominal = self.layout.nominal_episode(condition, variant)
            samples = {}
            for shard, table in zip(shards, tables, strict=True):
                if table.is_file() and (why := provenance.rows_problem(table)):
                    self.add(table, why)
                folder = self.layout.shard_recordings(condition, shard, variant)
                if recorded != "none" and self.is_current(table, folder):
                    self.recordings(table, folder, condition, only_failed=recorded == "failed")
                first, stop = shard_range(shard, size, n)
                self.found.episodes += (stop - first) * self.is_current(table)
                if resimulate > 0:
                    samples[table] = sample_ids(
                        first, stop, resimulate, seed=self.found.seed, key=self.rel(table)
                    )
            version = variant != NOMINAL and variant_version(self.config["variants"][variant])
            if version:
                again = self.elsewhere(version, qualified, slice_, gathered, nominal, samples)
            else:
                again = self.here(slice_, nominal, samples)
            if again is None:
                continue
            mujoco_version = version or self.installed_mujoco
            self.check(
                nominal,
                lambda p=nominal, f=again: self.reproduced(
                    p, lambda: f(p), lambda recomputed: json_difference(p, recomputed)
                ),
            )
            for table, ids in samples.items():
                self.check(
                    table,
                    lambda t=table, i=ids, f=again, v=mujoco_version: self.resimulated(
                        t, i, lambda: f(t), v
                    ),
                )

    def coverage(self) -> int:
        """Episodes to re-simulate per shard: every one if that fits the time budget
        (`verify.coverage`, timed on the first condition), and the check line says which."""
        n = self.config["states"]["n"]
        pairs = list(self.conditions())
        design = [(NOMINAL, c) for c in self.config["conditions"]]
        episodes = sum(  # of the shards there (a study not run has none)
            stop - first
            for layout, rollouts, size in (
                (self.layout, pairs, evaluation_shard_size(self.config)),
                (self.layout.development, design, self.config["rollout"]["shard_size"]),
            )
            for variant, condition in rollouts
            for shard in shard_ids(n, size)
            for first, stop in [shard_range(shard, size, n)]
            if layout.shard_table(condition, shard, variant).is_file()
        )
        qualified = pairs[0][1]  # the design's first condition: on the nominal model
        slice_ = config_slice("rollout", self.config, condition=qualified)
        timed = range(min(n, 5)) if self.layout.states.is_file() else []
        try:
            found = coverage(
                episodes,
                timed,
                lambda ids: resimulated_outcome(
                    slice_, self.model_file, self.layout.states, ids, repo_root=self.repo_root
                ),
            )
        except Exception:  # noqa: BLE001 - each re-simulated shard names what fails
            self.found.coverage = f"{DEFAULT_RESIMULATE} per shard: no episode could be timed"
            return DEFAULT_RESIMULATE
        self.found.coverage = found.why
        return found.per_shard

    def here(
        self, slice_: Mapping[str, Any], nominal: Path, samples: Mapping[Path, list[int]]
    ) -> Callable[[Path], Any]:
        """The condition's re-simulation on this MuJoCo, of an output: the nominal episode, or
        a shard table's sampled rows."""
        model, states, root = self.model_file, self.layout.states, self.repo_root
        return lambda path: (
            nominal_episode(slice_, model, repo_root=root)
            if path == nominal
            else resimulated_outcome(slice_, model, states, samples[path], repo_root=root)
        )

    def elsewhere(
        self,
        version: str,
        qualified: str,
        slice_: Mapping[str, Any],
        gathered: Path,
        nominal: Path,
        samples: Mapping[Path, list[int]],
    ) -> Callable[[Path], Any] | None:
        """The re-simulation of a variant on another MuJoCo version (as `here`), in its
        environment (`mjtrial.sim.simenv`): one process for every output of the condition the
        stamps judge current. None, and the check line says why, when that environment is
        not the one the run used."""
        lock = self.repo_root / lock_path(version)
        folder = lock.parent.relative_to(self.repo_root).as_posix()
        inputs = self.stamps.get(self.rel(gathered), {}).get("inputs")
        stamped = inputs.get("simulator_env") if isinstance(inputs, Mapping) else None
        stamped_sha = stamped.get("sha256") if isinstance(stamped, Mapping) else None
        build = f"`snakemake -c2 {folder}/{lock.name}` builds it"
        if not lock.is_file():
            why = f"{folder} not built; {build}"
        elif stamped_sha and stamped_sha != provenance.file_sha256(lock):
            why = f"the lock in {folder} differs from the one the run used"
        elif not env_python(lock).is_file():
            why = f"{folder} has no venv/bin/python: remove the folder, and {build}"
        else:
            why = None
        if why:
            self.found.elsewhere.setdefault(why, []).append(qualified)
            return None
        jobs = {self.rel(p): (slice_, ids) for p, ids in samples.items() if self.is_current(p)}
        if self.is_current(nominal):
            jobs[self.rel(nominal)] = (slice_, None)
        if not jobs:
            return None
        try:
            got = in_environment(
                env_python(lock),
                version,
                jobs,
                model_file=self.model_file,
                states_path=self.layout.states,
                repo_root=self.repo_root,
            )
        except (OSError, RuntimeError) as err:
            failed = err  # every output it would have checked says so

            def fails(path: Path) -> Any:
                raise failed

            return fails
        self.found.in_env.setdefault(folder, []).append(qualified)
        return lambda path: got[self.rel(path)]

    def recordings(self, table_path: Path, folder: Path, condition: str, *, only_failed: bool):
        """Compare every recorded episode's outcome and measures (its recording's `episode`
        property, no trajectory read) with its row of the shard's table, and check that every
        episode the config records has a recording: a row edited under a fresh stamp is named
        though it lies outside the re-simulated sample."""
        try:
            table = pq.read_table(table_path)
            records = {
                r["state_id"]: r for r in list_recordings(folder) if r.get("condition") == condition
            }
        except (OSError, ValueError) as err:
            self.add(
                table_path, f"its recordings cannot be read ({' '.join(str(err).split())[:100]})"
            )
            return
        columns = {c: table.column(c).to_pylist() for c in table.column_names}
        differ, unrecorded = [], []
        for i, state_id in enumerate(columns["state_id"]):
            row = {c: v[i] for c, v in columns.items()}
            record = records.pop(state_id, None)
            if record is None:
                if not (only_failed and row["success"]):
                    unrecorded.append(state_id)
                continue
            self.found.recorded += 1
            why = record_difference(record, row)
            if why:
                differ.append(f"state {state_id}: {why} in the table")
        for state_id in records:
            differ.append(f"state {state_id}: recorded, but the table has no row for it")
        if unrecorded:
            differ.append(f"no recording of states {unrecorded[:_SHOWN]} in {self.rel(folder)}")
        if differ:
            more = f" and {len(differ) - _SHOWN} more" if len(differ) > _SHOWN else ""
            self.add(
                table_path,
                f"its recorded episodes say otherwise: {'; '.join(differ[:_SHOWN])}{more}",
            )

    def resimulated(
        self,
        table_path: Path,
        ids: list[int],
        outcome: Callable[[], pa.Table],
        mujoco_version: str,
    ) -> str | None:
        """Why the table's rows of the states `ids` are not `outcome`, their re-simulation on
        MuJoCo `mujoco_version`."""
        table = pq.read_table(table_path)
        rows = {sid: i for i, sid in enumerate(table.column("state_id").to_numpy().tolist())}
        missing = [i for i in ids if i not in rows]
        if missing:
            return f"no row for states {missing[:_SHOWN]}"
        self.found.resimulated += len(ids)
        sampled = table.take(pa.array([rows[i] for i in ids]))
        why = self.reproduced(
            table_path,
            outcome,
            lambda again: table_difference(sampled, columns(again), what="re-simulated episodes"),
        )
        return why and why + _platform_note(provenance.read_stamp(table_path), mujoco_version)

    def reproduced(
        self,
        path: Path,
        resimulate: Callable[[], Any],
        difference: Callable[[Any], str | None],
    ) -> str | None:
        """Why `path` is not its re-simulation (`difference` of what `resimulate` gives), or
        None. If it is not, a second re-simulation that disagrees makes it irreproducible (the
        task's code is no function of its arguments), not tampered: its bytes may be the run's."""
        first = resimulate()
        if not (why := difference(first)):
            return None
        between = recomputed_difference(first, resimulate(), what="two re-simulations")
        if between:
            self.found.irreproducible[self.rel(path)] = not_reproduced(why, between)
            return None
        return why

    def pilot(self, resimulate: int) -> None:
        """The pilot's outputs under `development/`, checked as the evaluation's are: each
        table against its shards, a sample re-simulated on the development states, the rates."""
        development = _Checker(
            self.layout.development,
            self.config,
            self.repo_root,
            self.current,
            self.command_line,
            self.command,
        )
        development.found = self.found
        development.rollouts(
            resimulate,
            [(NOMINAL, c) for c in self.config["conditions"]],
            recorded="none",
            n=self._piloted_states(),
        )
        tables = {c: self.layout.development.rollout_table(c) for c in self.config["conditions"]}
        if self.is_current(*tables.values()):
            self.check(
                self.layout.pilot_summary,
                lambda: json_difference(
                    self.layout.pilot_summary,
                    summarize_pilot(
                        tables,
                        config_slice("pilot_summary", self.config),
                        repo_root=self.repo_root,
                    ),
                ),
            )

    def _piloted_states(self) -> int:
        """How many development states the pilot ran: its gathered tables' rows (a pilot run
        with `--config 'pilot={n: 4}'` is checked as what it was, whatever the config says
        now), else the config's `pilot.n`. A table edited to another length is caught by its
        rows' record and by its shards."""
        rows = []
        for condition in self.config["conditions"]:
            try:
                rows.append(pq.read_metadata(self.layout.development.rollout_table(condition)))
            except (OSError, ValueError):
                continue
        counts = {m.num_rows for m in rows}
        return counts.pop() if len(counts) == 1 and 0 not in counts else pilot_states(self.config)

    def analysis(self) -> None:
        layout, conditions = self.layout, list(self.config["conditions"])
        self.check(
            layout.summary,
            lambda: json_difference(
                layout.summary,
                summarize_tables(
                    states_path=layout.states,
                    rollout_tables={c: layout.rollout_table(c) for c in conditions},
                    nominal_files={c: layout.nominal_episode(c) for c in conditions},
                    analysis_slice=config_slice("analysis", self.config),
                    repo_root=self.repo_root,
                    registration_path=self._registration_read_by(layout.summary),
                ),
            ),
        )

    def looks(self) -> None:
        """A stopping rule's looks, each recomputed from the shard tables up to it: the stop
        (the summary's record of it is checked with the analysis)."""
        if "stopping" not in self.config:
            return
        falsifier = self.config["design"]["falsifier"]
        shards = shards_run(self.layout, self.config)
        for i, shard in enumerate(shards):
            tables = {
                role: [self.layout.shard_table(falsifier[role], s) for s in shards[: i + 1]]
                for role in ("treatment", "baseline")
            }
            if not self.is_current(*tables["treatment"], *tables["baseline"]):
                continue
            self.check(
                self.layout.look(shard),
                lambda s=shard, t=tables: json_difference(
                    self.layout.look(s),
                    look_record(
                        treatment_tables=t["treatment"],
                        baseline_tables=t["baseline"],
                        look_slice=config_slice("look", self.config),
                        shard=s,
                    ),
                ),
            )

    def _registration_read_by(self, path: Path) -> Path | None:
        """The registration an output's stamp records as its input, if any (the analysis
        marks comparisons it did not plan exploratory)."""
        recorded = provenance.read_stamp(path).get("inputs", {}).get(REGISTRATION_INPUT)
        if not isinstance(recorded, Mapping) or "path" not in recorded:
            return None
        in_repo = Path(self.repo_root) / recorded["path"]
        # a copied results folder holds it under its own root
        return in_repo if in_repo.is_file() else self.layout.root / Path(recorded["path"]).name

    def manifest(self) -> None:
        layout, conditions = self.layout, list(self.config["conditions"])
        shards = shards_run(layout, self.config)
        recorded = self.config["recording"]["episodes"] != "none"
        outputs = [layout.states]
        for c in conditions:
            outputs += [layout.rollout_table(c), layout.nominal_episode(c)]
            outputs += layout.shard_outputs(c, shards, recorded=recorded)
        if "stopping" in self.config:
            outputs += [layout.look(s) for s in shards]
        if recorded:
            outputs += [layout.failures, layout.failures_table]
        if not self.is_current(layout.summary, *outputs):
            return
        self.check(
            layout.manifest,
            lambda: json_difference(
                layout.manifest,
                manifest_record(
                    config=config_slice("manifest", self.config),
                    command_line=self.command_line,
                    command=self.command,
                    config_file=self.config_file,
                    summary_path=layout.summary,
                    outputs=outputs,
                    model_file=self.model_file,
                    repo_root=self.repo_root,
                    registration=layout.registration if layout.registration.exists() else None,
                )[0],
            ),
        )

    def report(self) -> None:
        layout = self.layout
        if not self.is_current(layout.summary, layout.manifest):
            return
        self.check(
            layout.report,
            lambda: markdown_difference(
                layout.report,
                report_text(
                    summary_path=layout.summary,
                    config=config_slice("report", self.config),
                    manifest_path=layout.manifest,
                    figure_paths=layout.figure_files(),
                    output=layout.report,
                    repo_root=self.repo_root,
                ),
            ),
        )

    def crate(self, stamps: Mapping[str, Mapping[str, Any]]) -> None:
        """The crate and its copy of the sources, rebuilt from the folder (`mjtrial.crate`)."""
        layout = self.layout
        if not self.is_current(layout.crate):
            return
        self.found.recomputed += 2
        try:
            differs = crate_differences(layout, repo_root=self.repo_root, stamps=stamps)
        except (OSError, ValueError) as err:
            why = " ".join(str(err).split())[:160]
            differs = {self.rel(layout.crate): f"cannot be recomputed ({why})"}
        for path, why in differs.items():
            self.found.differs[path] = f"differs from its recomputation: {why}"

    def studies(self) -> None:
        layout, config = self.layout, self.config
        for study in STUDIES:
            summary_path, report_path = layout.study_summary(study), layout.study_report(study)
            if study == "sensitivity":
                if not variant_names(config):
                    continue
                tables = {
                    v: {c: layout.rollout_table(c, v) for c in sensitivity_conditions(config)}
                    for v in [NOMINAL, *variant_names(config)]
                }
                recordings = version_recordings(config, layout)
                inputs = [p for by in tables.values() for p in by.values()]
                inputs += [f for by in recordings.values() for fs in by.values() for f in fs]

                def summarize(tables: Any = tables, recordings: Any = recordings) -> dict[str, Any]:
                    return sensitivity_summary(
                        study_slice=config_slice("sensitivity", config),
                        tables=tables,
                        recordings=recordings,
                        model_file=self.model_file,
                    )
            else:
                sweep = sweep_conditions(config)
                if not sweep:
                    continue
                tables = {v: layout.rollout_table(c) for v, c in sweep.items()}
                inputs = [layout.states, *tables.values()]

                def summarize(tables: Any = tables) -> dict[str, Any]:
                    return dose_response_summary(
                        study_slice=config_slice("dose_response", config),
                        states_path=layout.states,
                        tables=tables,
                        repo_root=self.repo_root,
                    )

            if not self.is_current(*inputs):
                continue
            summary = functools.cache(summarize)
            self.check(summary_path, lambda p=summary_path, f=summary: json_difference(p, f()))
            self.check(
                report_path,
                lambda s=study, p=report_path, f=summary: markdown_difference(
                    p,
                    study_report_text(
                        s,
                        f(),
                        report=p,
                        figures_dir=layout.figures_dir,
                        model_file=self.model_file,
                    ),
                ),
            )


def recompute(
    layout: Layout,
    config: Mapping[str, Any],
    *,
    repo_root: Path,
    current: Iterable[str],
    resimulate: int | None = None,
    seed: int | None = None,
    command_line: Mapping[str, Any] | None = None,
    command: str = "snakemake -c2",
    config_file: str = CONFIG_FILE,
    stamps: Mapping[str, Mapping[str, Any]] | None = None,
) -> Recomputation:
    """Recompute every light output of `layout` that the stamps judged current (`current`,
    repository-relative paths) and re-simulate `resimulate` episodes per shard (None: every
    one when that fits the time budget, else a sample, `verify.coverage`), drawn with `seed`
    (None: a fresh one, `fresh_seed`).

    `command_line` and `command` are what the manifest records of the run's command line
    (`mjtrial.stages.manifest`): the config values it was given, and the command itself;
    `config_file` the run's config file, repository-relative; `stamps` the stamps verify read
    (repository-relative path -> stamp), from which the crate is rebuilt.
    """
    checker = _Checker(layout, config, Path(repo_root), current, command_line or {}, command)
    checker.config_file = config_file
    checker.stamps = stamps or {}
    checker.found.seed = fresh_seed() if seed is None else seed
    if resimulate is None:
        resimulate = checker.coverage()
    checker.states()
    checker.rollouts(resimulate)
    checker.pilot(resimulate)
    checker.looks()
    checker.analysis()
    checker.manifest()
    checker.report()
    checker.studies()
    checker.crate(checker.stamps)
    return checker.found
