"""Every path under `results/<experiment>/`, and the pipeline's stages: the one place for both.

The Snakemake rules, `mjtrial verify`, `mjtrial replay`, the CLI, the report and the benchmarks
all take paths from a `Layout`. Each path method also accepts Snakemake wildcards as arguments
(`layout.rollout_table("{condition}")`), so the rules spell no path of their own.

The unit of rollout work is an episode group: a (variant, condition, shard). Today there is one
variant, `NOMINAL` (the model as committed), and one shard per condition, so a group is a
condition and its files sit directly under `rollouts/`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

RESULTS_DIR = "results"
# Models compiled by the workflow's processes, kept for the next (`physics.load_model`): in
# Snakemake's folder of the working folder, beside its own records; deleting it costs a compile.
COMPILED_MODELS = Path(".snakemake") / "mjtrial-compiled-models"
# Where `mjtrial replay` writes by default: beside the results, never inside a sealed folder.
REPLAYS_DIR = "replays"
CRATE_FILE = "ro-crate-metadata.json"  # RO-Crate's name for a crate's metadata file
CONFIG_FILE = "config/config.yaml"  # the design, relative to the repository root
NOMINAL = "nominal"  # the variant that is the model as committed
STUDIES = ("sensitivity", "dose_response")  # each a target: `snakemake -c2 sensitivity`
# Each study's figures, written as .png and .svg under figures/.
STUDY_FIGURES = {"sensitivity": "sensitivity_forest", "dose_response": "dose_response"}

# The report's figures, each written as .png and .svg under figures/.
FIGURES = (
    "success_by_condition",
    "success_by_band",
    "paired_outcomes",
    "failure_categories",
    "sample_traces",
)
FIGURE_FORMATS = ("png", "svg")
# A benchmark report's figures, the same way.
BENCHMARK_FIGURES = ("performance_profile",)

# What the crate stage copies into `source/` of a results folder, relative to the working
# folder: the workflow's files as they ran (the package itself comes from where it is imported,
# `src/mjtrial`). `pyproject.toml` and `README.md` make the copy installable (`pip install -e .`).
WORKFLOW_SOURCES = (
    "Snakefile",
    "workflow",
    "config",
    "models",
    "tasks",
    "profiles",
    "pyproject.toml",
    "README.md",
)


def script_path(script: str) -> str:
    """A workflow script's path relative to the repository root (`study` ->
    `workflow/scripts/study.py`)."""
    return f"workflow/scripts/{script}.py"


@dataclass(frozen=True)
class Stage:
    """A pipeline stage: its workflow script (`workflow/scripts/<script>.py`) and rule names.

    `rules` are the Snakemake rules that run the script; a stamp's rule is the stage's name,
    or `<stage>:<qualifier>` (`rollout:fast`, `states:development`).
    """

    name: str
    script: str

    @property
    def script_path(self) -> str:
        """The script's path relative to the repository root."""
        return script_path(self.script)


# In pipeline order.
STAGES: dict[str, Stage] = {
    s.name: s
    for s in (
        Stage("states", "states"),
        Stage("register", "register"),  # the design, registered before the first rollout
        Stage("rollout", "rollout"),
        # a stopping rule's look after each shard (`stopping`; a checkpoint)
        Stage("look", "look"),
        Stage("gather", "gather"),
        Stage("failures", "failures"),
        Stage("analysis", "analysis"),
        Stage("figures", "figures"),  # the report's figures
        Stage("manifest", "manifest"),
        Stage("report", "report"),
        Stage("seal", "seal"),
        Stage("sensitivity", "study"),
        Stage("dose_response", "study"),
        Stage("crate", "crate"),
        # the pilot: the design's conditions on the development states (`snakemake -c2 pilot`)
        Stage("pilot", "pilot_rollout"),
        Stage("pilot_gather", "pilot_gather"),
        Stage("pilot_summary", "pilot_summary"),
        Stage("train", "train"),  # a benchmark's tuning of one method, task and seed
        Stage("evaluate", "evaluate"),  # its parameters on a shard of the evaluation states
        Stage("evaluate_gather", "evaluate_gather"),  # the shards' rows in one table
        Stage("solvability", "solvability"),  # a benchmark's tasks under their reference
        Stage("benchmark", "benchmark"),  # the benchmark's summary
        Stage("closest_calls", "closest_calls"),  # a benchmark's episodes to watch
        Stage("benchmark_report", "benchmark_report"),
    )
}


# The stages whose stamp's qualifier is a condition (`rollout:<variant>/<condition>#<shard>`).
CONDITION_STAGES = ("rollout", "gather", "pilot", "pilot_gather")
# The pilot's stages: never part of `snakemake -c2`, never read by the evaluation.
PILOT_STAGES = ("pilot", "pilot_gather", "pilot_summary")

# The stages only a benchmark runs (`workflow/rules/benchmark.smk`); it also runs `states`.
BENCHMARK_STAGES = (
    "train",
    "evaluate",
    "evaluate_gather",
    "solvability",
    "benchmark",
    "closest_calls",
    "benchmark_report",
)


def shard_ids(n_states: int, shard_size: int) -> list[str]:
    """The shards of `n_states` states, `shard_size` each (the last may hold fewer)."""
    return [f"{i:05d}" for i in range((n_states + shard_size - 1) // shard_size)]


def evaluation_shard_size(config: Mapping[str, Any]) -> int:
    """States per rollout job of the evaluation states: a stopping rule's `look_every` (its
    look follows each shard, so the states a stop leaves out are never run), else
    `rollout.shard_size` (the development states, a pilot's, always run in those)."""
    if "stopping" in config:
        return int(config["stopping"]["look_every"])
    return int(config["rollout"]["shard_size"])


def shard_range(shard: str, shard_size: int, n_states: int) -> tuple[int, int]:
    """The state ids [first, stop) of one shard."""
    first = int(shard) * shard_size
    return first, min(first + shard_size, n_states)


@dataclass(frozen=True)
class Layout:
    """The files of one experiment's results folder, `root` (`results/<experiment>`)."""

    root: Path

    @classmethod
    def of(cls, experiment: str, *, base: Path | str = RESULTS_DIR) -> Layout:
        """The layout of `experiment` under `base` (relative paths stay relative)."""
        return cls(Path(base) / experiment)

    # -- states ---------------------------------------------------------------------------
    @property
    def states(self) -> Path:
        """The evaluation states: `state_id`, then the task's state parameters."""
        return self.root / "states.parquet"

    @property
    def development(self) -> Layout:
        """The development folder, laid out as an experiment's: its tuning states and the
        pilot's rollouts (`snakemake -c2 pilot`); nothing under it reaches a reported number."""
        return Layout(self.root / "development")

    @property
    def development_states(self) -> Path:
        """The tuning states, never reported."""
        return self.development.states

    @property
    def pilot_summary(self) -> Path:
        """The pilot's rates per condition on the development states."""
        return self.development.root / "analysis" / "pilot.json"

    # -- rollouts -------------------------------------------------------------------------
    def rollouts_dir(self, variant: str = NOMINAL) -> Path:
        if variant == NOMINAL:
            return self.root / "rollouts"
        return self.root / "variants" / variant / "rollouts"

    def rollout_table(self, condition: str, variant: str = NOMINAL) -> Path:
        """One row per episode of `condition` (`mjtrial.stages.rollout.ROLLOUT_COLUMNS`)."""
        return self.rollouts_dir(variant) / f"{condition}.parquet"

    def nominal_episode(self, condition: str, variant: str = NOMINAL) -> Path:
        """The nominal state's episode (each state parameter at its nominal value)."""
        return self.rollouts_dir(variant) / f"{condition}.nominal.json"

    def recordings(self, condition: str, variant: str = NOMINAL) -> Path:
        """The folder of `condition`'s shards: each shard's table and recordings."""
        return self.rollouts_dir(variant) / condition

    def shard_table(self, condition: str, shard: str, variant: str = NOMINAL) -> Path:
        """One shard's rows of the rollout table (`shard` from `shard_ids`)."""
        return self.recordings(condition, variant) / f"shard-{shard}.parquet"

    def shard_recordings(self, condition: str, shard: str, variant: str = NOMINAL) -> Path:
        """One shard's folder of Rerun recordings: a .rrd per recorded episode, a blueprint."""
        return self.recordings(condition, variant) / f"shard-{shard}"

    def shard_outputs(
        self, condition: str, shards: list[str], *, recorded: bool, variant: str = NOMINAL
    ) -> list[Path]:
        """Every shard's table, and its recordings when episodes are `recorded`."""
        out = [self.shard_table(condition, s, variant) for s in shards]
        if recorded:
            out += [self.shard_recordings(condition, s, variant) for s in shards]
        return out

    # -- stopping early ----------------------------------------------------------------------
    def look(self, shard: str) -> Path:
        """A stopping rule's look after `shard`: the e-value on the pairs run so far, and
        whether the experiment stops there."""
        return self.root / "analysis" / "looks" / f"look-{shard}.json"

    # -- downstream -----------------------------------------------------------------------
    @property
    def failures(self) -> Path:
        """Every failed episode's recording, gathered for the viewer."""
        return self.root / "replay" / "failures.rrd"

    def replay(
        self, condition: str, state_id: int, variant: str = NOMINAL, *, repo_root: Path
    ) -> Path:
        """Where `mjtrial replay` writes one re-simulated episode by default: outside the
        results folder, whose files the seal records (`replays/<experiment folder>/` in the
        repository, which git ignores)."""
        of = condition if variant == NOMINAL else f"{variant}_{condition}"
        return Path(repo_root) / REPLAYS_DIR / self.root.name / f"{of}_state{state_id}.rrd"

    @property
    def summary(self) -> Path:
        return self.root / "analysis" / "summary.json"

    @property
    def registration(self) -> Path:
        """The registered design (`mjtrial.design.registration`): the `register` job's output, which
        never registers over one (a registration Snakemake removed is put back)."""
        return self.root / "registration.json"

    @property
    def deviations(self) -> Path:
        """Each design that differed from the registration, noted when a run first started
        with it (`mjtrial.design.registration.note_deviation`): no rule's output, no rule's
        input."""
        return self.root / "deviations.json"

    @property
    def manifest(self) -> Path:
        return self.root / "manifest.json"

    @property
    def report(self) -> Path:
        return self.root / "report.md"

    @property
    def seal(self) -> Path:
        """The sha256 of every output, stamped: what `mjtrial verify` checks content against."""
        return self.root / "seal.json"

    @property
    def figures_dir(self) -> Path:
        return self.root / "figures"

    def figure(self, name: str, fmt: str) -> Path:
        return self.figures_dir / f"{name}.{fmt}"

    @property
    def logs_dir(self) -> Path:
        return self.root / "logs"

    def log(self, job: str) -> Path:
        """The log of one job: `rollout_fast`, `analysis`, ..."""
        return self.logs_dir / f"{job}.log"

    @property
    def failures_table(self) -> Path:
        """Every failed episode: condition, state, category, and whether failures.rrd holds it."""
        return self.root / "replay" / "failures.parquet"

    # -- sets of outputs ------------------------------------------------------------------
    def rollout_outputs(
        self, conditions: list[str], shards: list[str], *, recorded: bool, variant: str = NOMINAL
    ) -> list[Path]:
        """Every rollout output of these conditions: tables, nominal episodes, shards."""
        out: list[Path] = []
        for c in conditions:
            out += [self.rollout_table(c, variant), self.nominal_episode(c, variant)]
            out += self.shard_outputs(c, shards, recorded=recorded, variant=variant)
        return out

    def figure_files(self) -> list[Path]:
        return [self.figure(name, fmt) for name in FIGURES for fmt in FIGURE_FORMATS]

    # -- studies ------------------------------------------------------------------------
    def study_summary(self, study: str) -> Path:
        """`analysis/sensitivity.json`, `analysis/dose_response.json`."""
        return self.root / "analysis" / f"{study}.json"

    def study_report(self, study: str) -> Path:
        return self.root / f"report_{study}.md"

    def study_figure_files(self, study: str) -> list[Path]:
        return [self.figure(STUDY_FIGURES[study], fmt) for fmt in FIGURE_FORMATS]

    def study_seal(self, study: str) -> Path:
        """The sha256 of the study's outputs and of the rollouts it read."""
        return self.root / f"seal_{study}.json"

    # -- the crate --------------------------------------------------------------------------
    @property
    def crate(self) -> Path:
        """The RO-Crate metadata of the folder: a Provenance Run Crate of every sealed run."""
        return self.root / CRATE_FILE

    @property
    def source(self) -> Path:
        """The workflow's sources as they ran (`WORKFLOW_SOURCES` and `src/mjtrial`), copied
        by the crate stage: the crate's workflow is a file of the crate."""
        return self.root / "source"

    def sealed_outputs(
        self,
        conditions: list[str],
        shards: list[str],
        *,
        recorded: bool,
        looks: Sequence[str] = (),
    ) -> list[Path]:
        """Every output of the built-in experiment, in pipeline order: what the seal covers
        (`looks`: the shards a stopping rule looked after)."""
        return [
            self.states,
            *self.rollout_outputs(conditions, shards, recorded=recorded),
            *(self.look(s) for s in looks),
            *([self.failures, self.failures_table] if recorded else []),
            self.summary,
            self.manifest,
            self.report,
            *self.figure_files(),
        ]


@dataclass(frozen=True)
class BenchmarkLayout(Layout):
    """A benchmark's results folder (`results/<benchmark>`): each task's states in a folder laid
    out as an experiment's (`tasks/<task>/`), then one parameter file and one evaluation table
    per task, method and training seed; the summary, report, logs and seal as an experiment's."""

    def task(self, task: str) -> Layout:
        """The task's own folder: its evaluation and development states."""
        return Layout(self.root / "tasks" / task)

    def parameters(self, task: str, method: str, seed: int | str) -> Path:
        """A method's parameters for a task and training seed (the training job's output)."""
        return self.root / "training" / task / method / f"seed-{seed}.json"

    def solvability(self, task: str) -> Path:
        """The task's probe states under its reference controller, with their outcomes."""
        return self.root / "solvability" / f"{task}.parquet"

    def evaluation(self, task: str, method: str, seed: int | str) -> Path:
        """Those parameters' outcomes on the task's evaluation states (one row per state),
        gathered from its shards."""
        return self.root / "evaluation" / task / method / f"seed-{seed}.parquet"

    def evaluation_shard(self, task: str, method: str, seed: int | str, shard: str) -> Path:
        """One shard's rows of an evaluation (`shard` from `shard_ids`, the task's
        `rollout.shard_size`)."""
        return self.root / "evaluation" / task / method / f"seed-{seed}" / f"shard-{shard}.parquet"

    def benchmark_figure_files(self) -> list[Path]:
        return [self.figure(name, fmt) for name in BENCHMARK_FIGURES for fmt in FIGURE_FORMATS]

    @property
    def closest_calls(self) -> Path:
        """Each task's successes of smallest margin and episodes of largest, re-simulated."""
        return self.root / "replay" / "closest_calls.rrd"

    @property
    def closest_calls_table(self) -> Path:
        """The episodes of `closest_calls`: task, kind, rank, method, seed, state, margin."""
        return self.root / "replay" / "closest_calls.parquet"

    def benchmark_outputs(
        self, runs: Sequence[tuple[str, str, str]], shards: Mapping[str, Sequence[str]]
    ) -> list[Path]:
        """Every output of a benchmark, in pipeline order: what its seal covers. `runs` are its
        (task, method, seed) triples, `shards` each task's evaluation shards."""
        tasks = list(dict.fromkeys(task for task, _, _ in runs))
        return [
            *(p for t in tasks for p in (self.task(t).development_states, self.task(t).states)),
            *(self.solvability(t) for t in tasks),
            *(self.parameters(t, m, s) for t, m, s in runs),
            *(self.evaluation_shard(t, m, s, x) for t, m, s in runs for x in shards[t]),
            *(self.evaluation(t, m, s) for t, m, s in runs),
            self.summary,
            self.closest_calls,
            self.closest_calls_table,
            self.report,
            *self.benchmark_figure_files(),
        ]
