import re
import sys
from pathlib import Path

from mjtrial.config import pilot_states
from mjtrial.design.conditions import (
    all_conditions,
    policy_path,
    sensitivity_conditions,
    sweep_conditions,
    variant_names,
)
from mjtrial.design.registration import (
    RegistrationError,
    lost_deviation_note,
    note_deviation,
    rewritten_registration,
)
from mjtrial.files.layout import (
    FIGURES,
    NOMINAL,
    STUDY_FIGURES,
    Layout,
    evaluation_shard_size,
    script_path,
    shard_ids,
    shard_range,
)
from mjtrial.policy_files.file import policy_file_paths
from mjtrial.provenance import file_sha256, model_sha256
from mjtrial.sim.simenv import build as build_env
from mjtrial.sim.simenv import lock_path, variant_version, version_recordings
from mjtrial.sim.simenv import build_key as env_build_key
from mjtrial.stages.condition import episode_steps_of
from mjtrial.stages.look import stops
from mjtrial.stages.stamping import ConfigSlice, config_slice, stage_code_hash
from mjtrial.task import task_files

# Every path comes from the layout; rules pass wildcards ("{condition}") to its methods.
LAYOUT = Layout.of(config["experiment"])
CONDITIONS = list(config["conditions"])
# The nominal model's conditions: the design's, and those the dose-response sweep adds.
ALL_CONDITIONS = list(all_conditions(config))
VARIANTS = variant_names(config)
# Variants that name another MuJoCo version (mjtrial.sim.simenv), by name: their version.
VERSIONS = {
    v: variant_version(config["variants"][v])
    for v in VARIANTS
    if variant_version(config["variants"][v])
}
SWEEP = sweep_conditions(config)  # swept value -> the condition that runs it
SHARDS = shard_ids(config["states"]["n"], evaluation_shard_size(config))
# The pilot's shards: of its first pilot.n development states (default: all states.n).
PILOT_SHARDS = shard_ids(pilot_states(config), config["rollout"]["shard_size"])
SHARD_PATTERN = r"\d{5}"
RECORDED = config["recording"]["episodes"] != "none"
# A stopping rule (`stopping`): a look after each shard, a checkpoint (stopping.smk).
STOPPING = "stopping" in config


def run_shards():
    """The evaluation's shards that run: all of them; under a stopping rule, each up to the
    first look that stops. Each look is a checkpoint read in turn, so the next shard is asked
    for only once the look before it said go on (mjtrial.stages.look.shards_run reads the
    same files on disk for verify)."""
    if not STOPPING:
        return SHARDS
    shards = []
    for shard in SHARDS:
        shards.append(shard)
        if stops(checkpoints.look.get(shard=shard).output.look):
            break
    return shards


def run_looks():
    """The shards a stopping rule looked after (none without one)."""
    return run_shards() if STOPPING else []


def sealed_outputs(wildcards=None):
    """Every output of the experiment (`Layout.sealed_outputs`) of the shards that ran."""
    return LAYOUT.sealed_outputs(
        CONDITIONS, run_shards(), recorded=RECORDED, looks=run_looks()
    )


def sealed_inputs(wildcards):
    return as_inputs(sealed_outputs())


def sealed_folders(wildcards):
    return folders_of(sealed_outputs())


def run_shard_outputs(wildcards):
    """The design's conditions' shard tables that ran, and the looks (the manifest's)."""
    return [
        *(
            p
            for c in CONDITIONS
            for p in LAYOUT.shard_outputs(c, run_shards(), recorded=False)
        ),
        *(LAYOUT.look(s) for s in run_looks()),
    ]


def run_shard_recordings(wildcards):
    """The design's conditions' recordings folders that ran, as inputs (`as_inputs`)."""
    return as_inputs(shard_recordings(CONDITIONS))


def run_shard_folders(wildcards):
    """The design's conditions' recordings folders that ran, as a param."""
    return shard_recordings(CONDITIONS)


def run_shard_folders_by_condition(wildcards):
    return shard_folders(CONDITIONS)


# What only develops the design (its states, its pilot) notes no deviation: the pilot's
# discordance is what the registered power plan reads.
DEVELOPMENT_TARGETS = {"dev", "pilot"}


def note_design_deviation():
    """At the run's start, before any job removes a result: a design that differs from the
    registration is recorded with the results on disk now."""
    targets = set(getattr(workflow.dag_settings, "targets", None) or ())
    if not LAYOUT.registration.exists() or (targets and targets <= DEVELOPMENT_TARGETS):
        return  # a pilot develops the design: what it tries is no deviation
    try:
        # a registration rewritten since outputs were made under it is no design to run
        rewritten = rewritten_registration(LAYOUT)
        if rewritten:
            sys.exit(
                f"mjtrial: {LAYOUT.registration}: {rewritten[0]}; no job was started"
            )
        entry = note_deviation(config, layout=LAYOUT, repo_root=Path.cwd())
    except RegistrationError as err:
        sys.exit(f"mjtrial: {err}")
    if entry is not None:
        keys = ", ".join(c["key"] for c in entry["changes"])
        print(
            f"mjtrial: the design deviates from its registration: {keys}",
            file=sys.stderr,
        )


def say_lost_deviation_note():
    """The deviations noted are no rule's output: a deleted record is named here."""
    if workflow.is_main_process and (lost := lost_deviation_note(LAYOUT)):
        print(f"mjtrial: {LAYOUT.deviations}: {lost}", file=sys.stderr)


say_lost_deviation_note()


def qualified(wildcards):
    """`<condition>`, or `<variant>/<condition>` for a simulator variant's rollout."""
    variant = getattr(wildcards, "variant", None)
    return f"{variant}/{wildcards.condition}" if variant else wildcards.condition


def rollout_slice(wildcards):
    """The config a condition's rollout depends on: its own protocol parameters (and the
    variant's edits) only."""
    return config_slice("rollout", config, condition=qualified(wildcards))


def simulator_env(wildcards):
    """A variant's other MuJoCo: its environment's lock as the job's input, else none."""
    variant = getattr(wildcards, "variant", None)
    return (
        {"simulator_env": lock_path(VERSIONS[variant])} if variant in VERSIONS else {}
    )


def shard_bounds(wildcards):
    """The state ids [first, stop) of the job's shard."""
    return shard_range(
        wildcards.shard, evaluation_shard_size(config), config["states"]["n"]
    )


_EPISODE_STEPS = {}  # qualified condition -> its episode's physics steps


def rollout_priority(wildcards):
    """The job's physics steps, in thousands (its states times the condition's episode steps):
    Snakemake starts the ready job of highest priority, so the longest shards run first and
    the short ones fill the cores at the end (longest processing time first)."""
    key = qualified(wildcards)
    if key not in _EPISODE_STEPS:
        _EPISODE_STEPS[key] = episode_steps_of(
            rollout_slice(wildcards), Path(config["model"]), repo_root=Path.cwd()
        )
    first, stop = shard_bounds(wildcards)
    return (stop - first) * _EPISODE_STEPS[key] // 1000


def shard_tables(wildcards):
    """Every shard table of the job's condition (and variant), in state order."""
    variant = getattr(wildcards, "variant", NOMINAL)
    return [LAYOUT.shard_table(wildcards.condition, s, variant) for s in run_shards()]


def pilot_shard_tables(wildcards):
    """Every pilot shard table of the job's condition, in state order."""
    return [
        LAYOUT.development.shard_table(wildcards.condition, s) for s in PILOT_SHARDS
    ]


def pilot_shard_bounds(wildcards):
    """The development state ids [first, stop) of the pilot job's shard."""
    return shard_range(
        wildcards.shard, config["rollout"]["shard_size"], pilot_states(config)
    )


def shard_recordings_of(wildcards):
    """The job's shard's recordings folder (a rollout's param: one that records nothing
    removes an earlier run's, so the folder never holds recordings not of this run)."""
    variant = getattr(wildcards, "variant", NOMINAL)
    return str(LAYOUT.shard_recordings(wildcards.condition, wildcards.shard, variant))


def shard_recording_output(folder):
    """A shard's recordings folder as a named output, unless recording.episodes is none."""
    return {"recording": directory(folder)} if RECORDED else {}


def as_inputs(paths):
    """`paths` as rule inputs: files only. A shard's recordings folder is replaced by its shard
    table, written by the same job: Snakemake has no checksum of a folder and would compare
    its files' times, so a `touch` would rerun what reads it."""
    return [SHARD_TABLE_OF.get(str(p), p) for p in paths]


def folders_of(paths):
    """The shard recordings folders among `paths` (passed as params, beside `as_inputs`)."""
    return [str(p) for p in paths if str(p) in SHARD_TABLE_OF]


def shard_recordings(conditions, variant=NOMINAL):
    """Every shard's recordings folder of these conditions."""
    if not RECORDED:
        return []
    return [
        LAYOUT.shard_recordings(c, s, variant) for c in conditions for s in run_shards()
    ]


def shard_folders(conditions):
    """Condition -> its shards' recordings folders, as the layout names them for this config
    (stages never glob for shards: a folder left by an earlier shard size is not theirs).
    """
    return {
        c: (
            [str(LAYOUT.shard_recordings(c, s)) for s in run_shards()]
            if RECORDED
            else []
        )
        for c in conditions
    }


def one_of(names):
    """A wildcard constraint matching exactly one of `names`."""
    return "|".join(map(re.escape, names)) or "(?!)"


def sensitivity_tables():
    """(variant, condition) -> rollout table: the nominal model's first, then each variant's,
    for every condition the study reads (mjtrial.design.conditions.sensitivity_conditions).
    """
    return {
        (variant, c): LAYOUT.rollout_table(c, variant)
        for variant in [NOMINAL, *VARIANTS]
        for c in sensitivity_conditions(config)
    }


def sensitivity_recordings():
    """((variant, condition), shard folder) for each folder of recordings the sensitivity
    study reads (mjtrial.sim.simenv.version_recordings)."""
    return [
        ((variant, c), str(folder))
        for variant, by in version_recordings(config, LAYOUT).items()
        for c, folders in by.items()
        for folder in folders
    ]


# Each shard's recordings folder -> its table (the same job writes both).
SHARD_TABLE_OF = {
    str(LAYOUT.shard_recordings(c, s, v)): LAYOUT.shard_table(c, s, v)
    for v in [NOMINAL, *VARIANTS]
    for c in (ALL_CONDITIONS if v == NOMINAL else CONDITIONS)
    for s in SHARDS
}


def study_sealed_inputs(wildcards):
    return as_inputs(study_sealed(wildcards))


def study_sealed_folders(wildcards):
    return folders_of(study_sealed(wildcards))


def variant_outputs():
    """Every output of the variants' rollouts (what the sensitivity study's seal covers)."""
    return [
        path
        for variant in VARIANTS
        for path in LAYOUT.rollout_outputs(
            CONDITIONS, run_shards(), recorded=RECORDED, variant=variant
        )
    ]


def study_sealed(wildcards):
    """A study's outputs and the rollouts it read (the built-in ones are sealed already)."""
    study = wildcards.study
    own = [LAYOUT.study_summary(study), LAYOUT.study_report(study)]
    own += LAYOUT.study_figure_files(study)
    if study == "sensitivity":
        return own + variant_outputs()
    swept = [c for c in SWEEP.values() if c not in CONDITIONS]
    return own + LAYOUT.rollout_outputs(swept, run_shards(), recorded=RECORDED)


def study_figure_outputs(study):
    """A study's figure as named outputs, the PNG shown in Snakemake's HTML report."""
    name = STUDY_FIGURES[study]
    return {
        "figure": report(
            LAYOUT.figure(name, "png"),
            caption=f"../report/{name}.rst",
            category="Studies",
        ),
        "figure_svg": LAYOUT.figure(name, "svg"),
    }


def model_content(wildcards=None):
    """Content of the model, so a checkout that only touches its mtime reruns nothing."""
    return model_sha256(config["model"])


def task_content(wildcards=None):
    """Content of the task's files (or the name of an installed task), so that an edit to
    one reruns what it defines and a `touch` reruns nothing."""
    reference = config["task"]
    if not reference.endswith(".py"):
        return reference
    return ",".join(file_sha256(p) for p in task_files(Path(reference)))


def policy_files(wildcards):
    """The condition's policy file, its contract and the graph's external data files
    (`conditions.<name>.policy`), or none: the rollout's inputs, so that editing any reruns
    the condition."""
    policy = policy_path(all_conditions(config)[wildcards.condition])
    return [] if policy is None else [str(p) for p in policy_file_paths(policy)]


def policy_content(wildcards):
    """Content of the condition's policy files, so a `touch` reruns nothing."""
    return ",".join(file_sha256(p) for p in policy_files(wildcards))


def per_condition(path_of):
    """One path per condition: `path_of` is a layout method such as LAYOUT.rollout_table."""
    return [path_of(c) for c in CONDITIONS]


def figure_outputs():
    """The report's figures as named outputs: `<name>` (the PNG, shown in Snakemake's HTML
    report with its caption) and `<name>_svg`."""
    outputs = {}
    for name in FIGURES:
        outputs[name] = report(
            LAYOUT.figure(name, "png"),
            caption=f"../report/{name}.rst",
            category="Figures",
        )
        outputs[f"{name}_svg"] = LAYOUT.figure(name, "svg")
    return outputs


def registered_design(wildcards):
    """The registration (the analysis marks what it did not plan exploratory), written by the
    `register` job before the first rollout."""
    return str(LAYOUT.registration)
