"""Load and check the experiment's config: the schema first, then what a schema cannot say.

Every problem is reported as one line naming the file, the key and what was expected, before
any work starts, so a typo never costs a run or touches an earlier result.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jsonschema
import mujoco

from mjtrial import REPO_ROOT
from mjtrial.config import budget, passes
from mjtrial.config.read import (  # noqa: F401 - read from here by the workflow and the CLI
    MAX_CONFIG_BYTES,
    MAX_CONFIG_VALUES,
    ConfigError,
    merge_config,
    parse_config_args,
    parse_config_text,
    read_config_file,
    rerun_command,
    run_configuration,
)
from mjtrial.config.studies import _changes_nothing, _check_variant_applies, _unstable
from mjtrial.design.conditions import all_conditions, model_edits, policy_path, sweep_base
from mjtrial.design.states import ConstraintError, probe_constraint
from mjtrial.files.layout import CONFIG_FILE, NOMINAL, Layout
from mjtrial.files.schemas import packaged_schema
from mjtrial.policy_files.file import (
    PolicyFileError,
    contract_path,
    load_policy_file,
    policy_file_paths,
    policy_task,
)
from mjtrial.provenance import git_state
from mjtrial.provenance.model_closure import model_closure
from mjtrial.sim.physics import ModelError, load_model
from mjtrial.sim.simenv import model_overrides, variant_version
from mjtrial.stats import sequential
from mjtrial.stats.comparisons import comparisons_error
from mjtrial.studies.variants import variant_model
from mjtrial.task import BodyMass, BoundTask, ModelCheckError, Task, TaskError, call, load_task
from mjtrial.task.checks import (
    alike_conditions,
    check_observations,
    nominal_episode_sha256,
    run_task_code,
)

SCHEMA_PATH = REPO_ROOT / "workflow" / "schemas" / "config.schema.yaml"
DEFAULT_CONFIG = REPO_ROOT / CONFIG_FILE
# JSON Schema counts 200.0 as an integer; a count written as a float is a typo here.
_Validator = jsonschema.validators.extend(
    jsonschema.Draft202012Validator,
    type_checker=jsonschema.Draft202012Validator.TYPE_CHECKER.redefine(
        "integer", lambda _, value: isinstance(value, int) and not isinstance(value, bool)
    ),
)


def _non_finite(value: Any, key: str = "") -> tuple[str, float] | None:
    """The first NaN or infinite number in the config, with its key (JSON Schema's minimum
    and maximum let NaN through, since every comparison with NaN is false)."""
    if isinstance(value, float) and not math.isfinite(value):
        return key or "(top level)", value
    children = (
        value.items()
        if isinstance(value, Mapping)
        else enumerate(value)
        if isinstance(value, list)
        else ()
    )
    for k, v in children:
        found = _non_finite(v, f"{key}[{k}]" if isinstance(k, int) else f"{key}.{k}".lstrip("."))
        if found:
            return found
    return None


def _has_key(config: Mapping[str, Any] | None, key: str) -> bool:
    """Whether `config` holds the dotted `key` (`states.n`, `analysis.bands.mass[0]`)."""
    node: Any = config
    for part in key.replace("[", ".").replace("]", "").split("."):
        if isinstance(node, Mapping) and part in node:
            node = node[part]
        elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        else:
            return False
    return True


# What each schema keyword expects, in the config's words; `s` is the keyword's value.
_EXPECTATIONS = {
    "type": "expected {s}",
    "minimum": "expected >= {s}",
    "maximum": "expected <= {s}",
    "exclusiveMinimum": "expected > {s}",
    "exclusiveMaximum": "expected < {s}",
    "enum": "expected one of {s}",
    "minItems": "expected at least {s} items",
    "maxItems": "expected at most {s} items",
    "minLength": "expected a non-empty string",
    "minProperties": "expected at least {s} entries",
    "pattern": "expected a name matching {s}",
}


def _key(error: jsonschema.ValidationError, child: Any = None) -> str:
    """The key an error is about, from jsonschema's path (`$.states.ranges.mass[0]` ->
    `states.ranges.mass[0]`), optionally one level further down, at `child`."""
    key = error.json_path.removeprefix("$").removeprefix(".")
    if child is not None:
        key = f"{key}.{child}" if key else str(child)
    return key or "(top level)"


def _schema_message(error: jsonschema.ValidationError) -> str:
    """`key: expectation` for one schema error, naming the offending key itself."""
    keyword, value, got = error.validator, error.validator_value, error.instance
    if keyword == "additionalProperties":
        allowed = sorted(error.schema.get("properties", {}))
        unknown = min(set(got) - set(allowed), key=str)
        hint = f"one of {allowed}" if allowed else "no other keys"
        return f"{_key(error, unknown)}: unknown key; expected {hint}"
    if keyword == "required":
        missing = next(k for k in value if k not in got)
        return f"{_key(error, missing)}: missing; this key is required"
    if keyword == "oneOf":  # the forms' types: "an object or an array"
        types = [str(form.get("type", "value")) for form in value]
        forms = " or ".join(f"{'an' if t[0] in 'aeiou' else 'a'} {t}" for t in types)
        return f"{_key(error)}: expected {forms}, got {got!r}"
    template = _EXPECTATIONS.get(keyword)
    expectation = template.format(s=value) if template else error.message
    return f"{_key(error)}: {expectation}, got {got!r}"


def preflight(config: Mapping[str, Any], *, repo_root: Path) -> list[str]:
    """Checks on the run's surroundings, before any work: warnings to print, or a refusal.

    Refuses (`ConfigError`) a results folder that another experiment wrote, and a dirty
    repository when `provenance.require_clean` is set; a dirty repository otherwise gives one
    warning, since every output will be stamped dirty.
    """
    layout = Layout.of(config["experiment"])
    manifest = repo_root / layout.manifest
    if manifest.is_file():
        try:
            recorded = json.loads(manifest.read_text())["experiment"]
        except (ValueError, TypeError, KeyError, UnicodeDecodeError) as err:
            raise ConfigError(
                f"{layout.manifest}: corrupt ({type(err).__name__}: not the manifest this "
                "pipeline writes); expected a manifest.json naming its experiment: delete it to "
                "rebuild it"
            ) from None
        if recorded != config["experiment"]:
            raise ConfigError(
                f"{layout.root}/: written by experiment {recorded!r} (manifest.json); expected "
                f"{config['experiment']!r}: choose another experiment name or move the folder"
            )
    git = git_state(repo_root)
    if git.get("available") and git.get("dirty"):
        if config["provenance"]["require_clean"]:
            raise ConfigError(
                "provenance.require_clean is true and the repository has uncommitted changes; "
                "expected a clean tree (commit or stash them)"
            )
        return [
            "Warning: the repository has uncommitted changes: every output will be stamped "
            f"dirty: true with the diff's hash {git['diff_sha256'][:12]}"
        ]
    return []


def load_config(
    path: str | Path = DEFAULT_CONFIG, *, repo_root: Path = REPO_ROOT
) -> dict[str, Any]:
    """Read a YAML config file and check it (see `check_config`) against the files of
    `repo_root` (its task, model and policy files)."""
    config = read_config_file(path)
    check_config(config, source=str(path), repo_root=repo_root)
    return config


def _check_task_model(
    config: Mapping[str, Any], task: Task, *, repo_root: Path, fail: Callable[[str, str], None]
) -> None:
    """The task's model is the config's (when the config names an existing file)."""
    if not isinstance(config.get("model"), str):
        return
    model_file = (repo_root / config["model"]).resolve()
    if not model_file.is_relative_to(repo_root.resolve()):
        return  # refused as outside the repository, below
    if model_file.is_file() and Path(task.model).resolve() != model_file:
        shown = os.path.relpath(Path(task.model).resolve(), repo_root.resolve())
        fail("task", f"its model is {shown}; expected the config's model {config['model']}")


def policy_path_problem(policy: str, *, repo_root: Path) -> str | None:
    """Why a policy file path is refused, or None: it must be written relative to the
    repository without `..` (as stamps, the crate and the zip record it: `../<checkout>/...`
    names this checkout's folder, which the zip's unpacked copy has not), and neither the graph
    nor its contract may be a symlink to a file outside the repository (verify and the zip
    check what is inside it only)."""
    root = Path(repo_root).resolve()
    written = Path(policy)
    if written.is_absolute() or ".." in written.parts:
        return (
            f"expected a path relative to the repository without '..' "
            f"(policies/<name>/<file>.onnx), got {policy!r}"
        )
    for file in (root / written, contract_path(root / written)):
        if file.exists() and not file.resolve().is_relative_to(root):
            shown = file.relative_to(root).as_posix()
            return f"{shown}: a symlink to a file outside the repository; expected a file inside it"
    return None


def _policy_tasks(
    config: Mapping[str, Any], task: Task, *, repo_root: Path, fail: Callable[[str, str], None]
) -> dict[str, Task]:
    """The task each condition that names a policy file runs (`policy_file.policy_task`), the
    file and its contract checked against the task and the graph: one line naming the key and
    the file otherwise."""
    out = {}
    root = Path(repo_root).resolve()
    for name, condition in all_conditions(config).items():
        policy = policy_path(condition)
        if not policy:
            continue
        key = f"conditions.{name}.policy"
        path = (root / policy).resolve()
        if problem := policy_path_problem(policy, repo_root=root):
            fail(key, problem)
        try:
            out[name] = policy_task(task, load_policy_file(path, task))
        except PolicyFileError as err:
            fail(key, str(err).replace(f"{root}/", ""))
    return out


def _check_privileged(
    config: Mapping[str, Any],
    task: Task,
    *,
    policy_tasks: Mapping[str, Task],
    repo_root: Path,
    fail: Callable[[str, str], None],
) -> None:
    """The course's cheap test of a policy: every observation it reads has a real-world source,
    or is allowed, with a reason, in `privileged_observations`; an allowance is for a
    privileged observation a policy reads (the task's, or a condition's policy file's)."""
    allowed = config.get("privileged_observations") or {}
    used: dict[str, str] = {}
    own = len(policy_tasks) < len(all_conditions(config))  # a condition runs the task's policy
    for key, reader in [*([("task", task)] if own else []), *policy_tasks.items()]:
        try:
            used |= check_observations(reader, allowed)
        except TaskError as err:
            where = "task" if key == "task" else f"conditions.{key}.policy"
            fail(where, str(err).replace(f"{Path(repo_root).resolve()}/", ""))
    for name in allowed:
        if name not in used:
            fail(
                f"privileged_observations.{name}",
                f"not a privileged observation the policy reads; expected one of {sorted(used)}"
                if used
                else "the policy reads no privileged observation; expected no allowance",
            )


def _check_task_states(
    config: Mapping[str, Any], task: Task, *, repo_root: Path, fail: Callable[[str, str], None]
) -> None:
    """`states.ranges` gives a range to each of the task's state parameters (a body's mass a
    positive one) and to nothing else."""
    names = [p.name for p in task.state_parameters]
    ranges = config["states"]["ranges"]
    for name in names:
        if name not in ranges:
            fail(f"states.ranges.{name}", f"missing; expected a range for each of {names}")
    for name in ranges:
        if name not in names:
            fail(f"states.ranges.{name}", f"not a state parameter of the task; expected {names}")
    for p in task.state_parameters:
        low = ranges[p.name][0]
        if isinstance(p.apply, BodyMass) and not low > 0:
            fail(f"states.ranges.{p.name}[0]", f"expected > 0, got {low}")
    distributions = config["states"].get("distributions") or {}
    for name, given in distributions.items():
        key = f"states.distributions.{name}"
        if name not in names:
            fail(key, f"not a state parameter of the task; expected one of {names}")
        elif given["kind"] == "normal" and isinstance(
            task.state_parameters[names.index(name)].apply, BodyMass
        ):
            fail(key, "a normal draws masses at or below 0; expected truncated_normal")


def pilot_states(config: Mapping[str, Any]) -> int:
    """How many development states the pilot runs (the first ones): `pilot.n`, by default all of
    them (`states.n`)."""
    return int((config.get("pilot") or {}).get("n", config["states"]["n"]))


def _check_stopping(config: Mapping[str, Any], *, fail: Callable[[str, str], None]) -> None:
    """A stopping rule's settings that the schema cannot check: one error budget for the
    falsifier, a null of no difference, and a look before the maximum N."""
    falsifier, stopping = config["design"]["falsifier"], config["stopping"]
    if falsifier["threshold"] != 0:  # the sequential test's null is McNemar's: no difference
        fail(
            "design.falsifier.threshold",
            f"expected 0 with a stopping rule (its null is no paired difference), got "
            f"{falsifier['threshold']}",
        )
    fixed = (1.0 - float(config["analysis"]["confidence"])) / 2
    if stopping["alpha"] > fixed + 1e-12:
        fail(
            "stopping.alpha",
            f"expected at most {fixed:g}, the one-sided error of the falsifier's verdict at "
            f"analysis.confidence {config['analysis']['confidence']:g} (the stopping rule's "
            f"test decides it), got {stopping['alpha']:g}",
        )
    n, every = config["states"]["n"], stopping["look_every"]
    if every >= n:
        fail(
            "stopping.look_every",
            f"expected fewer than states.n ({n}) states between looks, or the rule cannot stop "
            f"before N, got {every}",
        )
    # the best a look before N can see: every pair so far discordant to the treatment
    last = (n - 1) // every * every
    threshold = sequential.calibrated_threshold(n, float(stopping["alpha"]))["threshold"]
    if sequential.e_value(last, last) < threshold:
        fail(
            "stopping.look_every",
            f"expected a look before N at which the rule can stop: at the last one ({last} "
            f"states) even every pair to {falsifier['treatment']} gives an e-value of "
            f"{sequential.e_value(last, last):.3g}, under the threshold {threshold:.3g} "
            f"(N = {n}, alpha {stopping['alpha']:g}), got {every}",
        )


def check_config(
    config: Mapping[str, Any],
    *,
    source: str = "config/config.yaml",
    repo_root: Path = REPO_ROOT,
    overrides: Mapping[str, Any] | None = None,
) -> None:
    """Raise `ConfigError` (one line: file, key, expectation) unless the config is runnable.

    `overrides` are the values given on the command line (`--config`, `--configfile`): an
    error about one of them names the command line rather than `source`.
    """
    if not isinstance(config, Mapping):
        raise ConfigError(f"{source}: expected a mapping of keys at the top level")
    key = None
    if passes.keeping():  # in the workflow's Snakemake process (the Snakefile says so)
        key = passes.check_key(
            config,
            repo_root=Path(repo_root),
            schemas=SCHEMA_PATH.parent,
            policies=_policy_files(config, repo_root=Path(repo_root)),
        )
    if passes.passed(key):
        return
    _check(config, source=source, repo_root=Path(repo_root), overrides=overrides)
    passes.remember(key)


def _policy_files(config: Mapping[str, Any], *, repo_root: Path) -> list[Path] | None:
    """Every file of every condition's policy file (`policy_file_paths`): what a check's key
    hashes; None where the config cannot say (then no key: the check runs and says why)."""
    try:
        named = [policy_path(c) for c in all_conditions(config).values()]
        return [p for n in named if isinstance(n, str) for p in policy_file_paths(repo_root / n)]
    except Exception:  # noqa: BLE001 - a config the check refuses
        return None


def _check(
    config: Mapping[str, Any],
    *,
    source: str,
    repo_root: Path,
    overrides: Mapping[str, Any] | None,
) -> None:
    def fail(key: str, expectation: str) -> None:
        where = "--config" if _has_key(overrides, key) else source
        raise ConfigError(f"{where}: {key}: {expectation}")

    bad = _non_finite(dict(config))
    if bad:
        fail(bad[0], f"expected a finite number, got {bad[1]}")
    schema = packaged_schema(SCHEMA_PATH)
    task = None
    if isinstance(config.get("task"), str) and config["task"]:
        # the task declares what conditions, the taxonomy, a sweep and the bands may hold
        try:
            task = load_task(config["task"], repo_root=Path(repo_root))
        except TaskError as err:
            fail("task", str(err))
        _check_task_model(config, task, repo_root=Path(repo_root), fail=fail)
        schema = task.config_schema(schema)
    error = jsonschema.exceptions.best_match(_Validator(schema).iter_errors(dict(config)))
    if error is not None:
        key, _, expectation = _schema_message(error).partition(": ")
        fail(key, expectation)

    conditions = config["conditions"]
    falsifier = config["design"]["falsifier"]
    for role in ("treatment", "baseline"):
        if falsifier[role] not in conditions:
            fail(
                f"design.falsifier.{role}",
                f"expected one of the conditions {sorted(conditions)}, got {falsifier[role]!r}",
            )
    if falsifier["treatment"] == falsifier["baseline"]:
        fail("design.falsifier.baseline", "expected a condition other than the treatment")
    if "stopping" in config:
        _check_stopping(config, fail=fail)
    wrong = comparisons_error(config["analysis"], falsifier, list(conditions))
    if wrong:
        fail(*wrong)
    _check_task_states(config, task, repo_root=Path(repo_root), fail=fail)
    policy_tasks = _policy_tasks(config, task, repo_root=Path(repo_root), fail=fail)
    _check_privileged(config, task, policy_tasks=policy_tasks, repo_root=Path(repo_root), fail=fail)
    for name, (low, high) in config["states"]["ranges"].items():
        if not low < high:
            fail(
                f"states.ranges.{name}", f"expected [low, high] with low < high, got {[low, high]}"
            )
    if config["states"]["development_seed"] == config["states"]["seed"]:
        fail(
            "states.development_seed",
            "expected a seed other than states.seed (development and evaluation states must be "
            "disjoint)",
        )
    for name, edges in config["analysis"]["bands"].items():
        key = f"analysis.bands.{name}"
        if any(high <= low for low, high in zip(edges[:-1], edges[1:], strict=True)):
            fail(key, f"expected strictly increasing edges, got {edges}")
        parameter = name.removeprefix("abs_")
        low, high = config["states"]["ranges"][parameter]
        if name.startswith("abs_"):
            low, high = 0.0, max(abs(low), abs(high))
        if edges[0] > low or edges[-1] < high:
            fail(key, f"expected edges covering the range of {name} [{low}, {high}], got {edges}")
    if config["analysis"]["first_k"] > config["states"]["n"]:
        fail("analysis.first_k", f"expected at most states.n ({config['states']['n']})")
    if pilot_states(config) > config["states"]["n"]:
        fail(
            "pilot.n",
            f"expected at most states.n ({config['states']['n']}, the development states' count: "
            f"the pilot runs the first pilot.n of them), got {pilot_states(config)}",
        )
    too_many = budget.job_count_problem(config, len(all_conditions(config)))
    if too_many:
        fail(*too_many)
    model_file = (repo_root / config["model"]).resolve()
    if not model_file.is_relative_to(Path(repo_root).resolve()):
        fail(
            "model",
            f"expected a file inside the repository, got {config['model']!r} (copy it under "
            "models/, so that stamps record it and mjtrial verify can check it)",
        )
    if not model_file.is_file():
        fail("model", f"expected an existing model file, got {config['model']!r} (not found)")
    try:
        model = load_model(model_file)
    except ModelError as err:
        fail("model", str(err).replace(str(model_file), config["model"]))
    try:
        bound = BoundTask.of(task, model)
    except ModelCheckError as err:
        fail("model", f"{config['model']}: {err.problem}")
    except TaskError as err:
        fail("task", str(err))
    root = Path(repo_root).resolve()
    for path in model_closure(model_file)[1:]:
        if not path.is_relative_to(root):
            fail(
                "model",
                f"{config['model']} loads {os.path.relpath(path, root)}, outside the repository; "
                "expected every file it includes or names (meshes, textures) inside it, so that "
                "stamps record them and mjtrial verify can check them",
            )
    rate_hz = float(config["recording"]["rate_hz"])
    groups = _conditions_by_model(all_conditions(config), bound, model_file, policy_tasks, fail)
    try:
        problems = [
            problem
            for on_model, conditions in groups
            for problem in budget.episode_problems(
                conditions, on_model, timestep_key="model", rate_hz=rate_hz
            )
        ]
    except TaskError as err:
        fail("task", str(err))
    for key, expectation in problems:
        fail(key, f"{config['model']}: {expectation}" if key == "model" else expectation)
    # The task's own code on every condition's nominal episode: a bad shape, an exception, a
    # non-finite control or a parameter never applied is one line here, before any rollout.
    taxonomy = config["failure_taxonomy"]
    given = {t.name: float(taxonomy.get(t.name, t.default)) for t in task.thresholds}
    printer = mujoco.get_mju_user_warning()  # an unstable model is said below, in one line
    mujoco.set_mju_user_warning(lambda _: None)
    try:
        for on_model, conditions in groups:
            try:
                run_task_code(
                    on_model,
                    conditions,
                    thresholds=given,
                    allowed_privileged=config.get("privileged_observations") or {},
                )
            except PolicyFileError as err:  # a condition's policy file against its condition
                (name,) = conditions
                relative = str(err).replace(f"{Path(repo_root).resolve()}/", "")
                fail(f"conditions.{name}.policy", relative)
    except TaskError as err:
        fail("task", str(err))
    finally:
        mujoco.set_mju_user_warning(printer)
    if task.valid_state is not None:  # the states job's probe, here before any job
        try:
            probe_constraint(
                seed=config["states"]["seed"],
                ranges=config["states"]["ranges"],
                parameters=[p.name for p in task.state_parameters],
                valid=lambda values: call(task, "valid_state", task.valid_state, values),
                distributions=config["states"].get("distributions"),
            )
        except ConstraintError as err:
            fail("task", f"{task.source or task.name}: valid_state: {err}")
        except TaskError as err:
            fail("task", str(err))
    nominal = nominal_episode_sha256(bound)
    runs: dict[str, tuple[BoundTask, str]] = {}  # each designed condition's nominal episode
    for on_model, conditions in groups:
        if on_model.model is not bound.model and nominal_episode_sha256(on_model) == nominal:
            (name,) = conditions  # a condition with edits of the model has a group of its own
            fail(f"conditions.{name}.model", _changes_nothing(bound.model, on_model.model))
        designed = {n: c for n, c in conditions.items() if n in config["conditions"]}
        unstable = _unstable(on_model, designed, config["failure_taxonomy"], runs=runs)
        if unstable:
            fail("model", f"{config['model']}: {unstable}")
    same = alike_conditions(runs, config["conditions"], config["failure_taxonomy"])
    if same:
        first, second = same
        fail(
            f"conditions.{second}",
            f"runs bit for bit as condition {first!r}: the nominal episode and each state "
            "parameter at its low and its high value (the others nominal) give the same "
            "trajectories, so the two would be compared as if they differed; expected "
            "conditions that differ in what the episode does (a parameter the task reads, an "
            "edit of the physics, another policy)",
        )
    _check_studies(config, schema, model_file, bound, fail)


def _conditions_by_model(
    conditions: Mapping[str, Mapping[str, Any]],
    bound: BoundTask,
    model_file: Path,
    policy_tasks: Mapping[str, Task],
    fail: Callable[[str, str], None],
) -> list[tuple[BoundTask, dict[str, Mapping[str, Any]]]]:
    """The conditions with the model and task each runs on: those without edits or a policy
    file on the committed model (`bound`), each with `model` edits on its own edited model, the
    edits checked against the model (one line naming the key: an unknown element or attribute,
    a wrong value), each with a policy file as its own task (`policy_tasks`)."""
    plain = {n: c for n, c in conditions.items() if not model_edits(c) and n not in policy_tasks}
    groups = [(bound, plain)] if plain else []
    for name, condition in conditions.items():
        if name in plain:
            continue
        key = f"conditions.{name}.model"
        task = policy_tasks.get(name, bound.task)
        if not model_edits(condition):
            groups.append((BoundTask.of(task, bound.model), {name: condition}))
            continue
        try:
            model, _ = variant_model(
                model_file, {}, key_prefix=key, then=[(model_edits(condition), key)]
            )
        except ValueError as err:  # one line, "<key>: <expectation>" (ModelError included)
            named, _, expectation = str(err).partition(": ")
            fail(*((named, expectation) if named.startswith(key) else (key, str(err))))
        try:
            groups.append((BoundTask.of(task, model), {name: condition}))
        except TaskError as err:
            fail(key, str(err))
    return groups


def _check_studies(
    config: Mapping[str, Any],
    schema: Mapping[str, Any],
    model_file: Path,
    bound: BoundTask,
    fail: Callable[[str, str], None],
) -> None:
    """Variants that apply to the model and keep the protocol's step; a sweep whose conditions
    are valid ones. An unstable variant is not refused: its verdict is `invalid`. A variant
    named as the committed model, one that changes nothing, two that make the same model, and
    one that a condition's own edits undo (`_check_variant_applies`) are refused: each would be
    counted in "survives N of M" without testing anything new. "The same" is the same
    simulation (`task_checks.nominal_episode_sha256`), not the same bytes."""
    variants = config.get("variants") or {}
    task = bound.task
    seen = {(None, nominal_episode_sha256(bound)): NOMINAL} if variants else {}
    for name, variant in variants.items():
        key = f"variants.{name}"
        if name == NOMINAL:
            fail(key, f"{NOMINAL!r} is reserved for the model as committed; expected another name")
        version = variant_version(variant)
        if version == mujoco.__version__:
            fail(f"{key}.mujoco", f"{version} is the MuJoCo that runs; expected another version")
        try:  # the edits are checked on this MuJoCo; the version's own runs in its environment
            model, _ = variant_model(model_file, model_overrides(variant), key_prefix=key)
        except ValueError as err:  # one line, "<key>: <expectation>" (ModelError included)
            named, _, expectation = str(err).partition(": ")
            if named.startswith(key):
                fail(named, expectation)
            fail(key, str(err))
        try:
            on_variant = BoundTask.of(task, model)
        except ModelCheckError as err:
            fail(key, err.problem)
        except TaskError as err:
            fail(key, str(err))
        simulated = (version, nominal_episode_sha256(on_variant))
        if seen.get(simulated) == NOMINAL:
            fail(key, _changes_nothing(bound.model, model))
        if simulated in seen:
            fail(
                key,
                f"the same simulation as variants.{seen[simulated]}; expected each variant once",
            )
        seen[simulated] = name
        _check_variant_applies(config, name, model_file, task, fail)
        for problem in budget.episode_problems(
            config["conditions"],
            on_variant,
            timestep_key=f"{key}.option.timestep",
            rate_hz=float(config["recording"]["rate_hz"]),
        ):
            fail(*problem)
    if "sweep" not in config:
        return
    sweep = config["sweep"]
    base = sweep_base(config)
    if base not in config["conditions"]:
        fail("sweep.base", f"expected one of the conditions {sorted(config['conditions'])}")
    # The condition's schema with the definitions it refers to ($defs/hold).
    condition_schema = {
        **schema["properties"]["conditions"]["additionalProperties"],
        "$defs": schema["$defs"],
    }
    for i, value in enumerate(sweep["values"]):
        condition = {**config["conditions"][base], sweep["parameter"]: value}
        error = jsonschema.exceptions.best_match(
            _Validator(condition_schema).iter_errors(condition)
        )
        if error is not None:
            fail(f"sweep.values[{i}]", _schema_message(error).partition(": ")[2])
    if "reference" in sweep and sweep["reference"] not in sweep["values"]:
        fail("sweep.reference", f"expected one of sweep.values, got {sweep['reference']}")
    reference = sweep.get("reference", max(sweep["values"]))
    if "toward" not in sweep and min(sweep["values"]) < reference < max(sweep["values"]):
        fail(
            "sweep.toward",
            f"expected smaller or larger: the reference {reference:g} lies inside the sweep, "
            "so which way values cost must be said",
        )
