"""The report's Setup section: what ran, read from the manifest, the config and the compiled
model (the model's parts from `mjtrial.report.model`, `.actuators`, `.solver`)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from mjtrial import provenance
from mjtrial.design.conditions import condition_record, model_edits, policy_path
from mjtrial.design.states import NORMAL, TRUNCATED_NORMAL, UNIFORM, distribution
from mjtrial.policy_files.file import read_contract
from mjtrial.report.actuators import actuator_lines
from mjtrial.report.labels import markdown_table, pct, setting
from mjtrial.report.model import (
    action_lines,
    contact_lines,
    equality_lines,
    joint_lines,
    model_files_text,
)
from mjtrial.report.solver import solver_line
from mjtrial.sim.contacts import describe_contact_changes
from mjtrial.stages.condition import condition_model
from mjtrial.stages.stamping import config_slice
from mjtrial.studies.variants import variant_model
from mjtrial.task import BoundTask, ClosedLoop, Control, Task, call
from mjtrial.task.actions import bind_actions


def _development_use(config: Mapping[str, Any]) -> str:
    """What the design says the development states were for, in its own words, never assumed."""
    said = " ".join(str(config.get("design", {}).get("development_split") or "").split())
    return (
        f' (the design: "{said.rstrip(".")}")'
        if said
        else " (the design says nothing of their use)"
    )


def _task_lines(record: Mapping[str, Any] | None) -> list[str]:
    """The task, its controller, what its policy reads from which source, and any privileged
    observation the design allows, with its reason (from the manifest's task record)."""
    if not record:
        return []
    lines = [f"- Task: {record['title']} (`{record['reference']}`), {record['controller']}."]
    if record["observations"]:
        errors = record.get("observation_errors", {})
        read = ", ".join(
            f"{name} ({source or '**privileged**: no real-world source'}"
            + "".join(f"; {role}: `{p}`" for role, p in errors.get(name, {}).items())
            + ")"
            for name, source in record["observations"].items()
        )
        lines.append(f"- The policy reads: {read}.")
    for name, reason in record.get("privileged_observations", {}).items():
        lines.append(f"- Privileged observation allowed by the design: {name}: {reason}.")
    return lines


def _redrawn_text(redrawn: Mapping[str, int] | None) -> str:
    """How many drawn states `valid_state` rejected, per set (the manifest's record)."""
    if not redrawn:
        return "the manifest's `states_redrawn` counts those rejected."
    counts = [
        f"{redrawn[k]} for the {k} states" for k in ("evaluation", "development") if k in redrawn
    ]
    return f"draws rejected and redrawn: {', '.join(counts)}."


_ACTION_SCALE = {
    "ctrlrange": "a column in [-1, 1] mapped onto its actuators' ctrlrange, then clipped",
    "raw": "a column is the ctrl, clipped to a limited actuator's ctrlrange",
}


def _condition_actions(
    task: Task, condition: Mapping[str, Any], repo_root: Path
) -> tuple[tuple[Any, ...], str]:
    """The actions a condition's policy drives (its policy file's contract, else the task's)
    and how its contract scales them ("" for the task's policy)."""
    policy = policy_path(condition)
    if policy is None:
        return tuple(task.controller.actions), ""
    contract = read_contract(Path(repo_root) / policy)
    actions = contract.actions or tuple(Control(a) for a in contract.actuators)
    where = provenance.path_in_repo(contract.source, repo_root) or contract.source
    return actions, f"its contract `{where}`: {_ACTION_SCALE[contract.action_scale]}"


def _initial_states_lines(states: Mapping[str, Any], task: Task, bitgen: str) -> list[str]:
    """How the initial states were drawn: the generator, then each parameter's distribution
    (uniform in its range unless `states.distributions` says otherwise)."""
    parameters = [p for p in task.state_columns[1:] if p in states["ranges"]]
    drawn = {p: distribution(p, states["ranges"], states.get("distributions")) for p in parameters}
    head = (
        f"Initial states: n = {states['n']}, drawn with numpy's `default_rng({states['seed']})` "
        f"({bitgen}), one "
    )
    order = f"draw of n values per parameter in the order {', '.join(task.state_columns[1:])}"
    if all(d["kind"] == UNIFORM for d in drawn.values()):
        rows = [[p, f"{d['low']:g}", f"{d['high']:g}", task.unit_of(p)] for p, d in drawn.items()]
        return [
            f"{head}uniform {order}:",
            "",
            *markdown_table(["parameter", "low", "high", "unit"], rows),
        ]
    words = {
        UNIFORM: lambda d: f"uniform in [{d['low']:g}, {d['high']:g}]",
        NORMAL: lambda d: f"normal, mean {d['mean']:g}, std {d['std']:g} (not truncated)",
        TRUNCATED_NORMAL: lambda d: (
            f"normal, mean {d['mean']:g}, std {d['std']:g}, truncated to "
            f"[{d['low']:g}, {d['high']:g}]"
        ),
    }
    rows = [[p, words[d["kind"]](d), task.unit_of(p)] for p, d in drawn.items()]
    return [
        f"{head}{order} (a normal by numpy's `normal`, a truncated normal by scipy's "
        "`truncnorm.ppf` at one `uniform` draw):",
        "",
        *markdown_table(["parameter", "distribution", "unit"], rows),
    ]


def between_actions_text(task: Task, model: mujoco.MjModel) -> str:
    """What acts between two of the policy's actions, for the setup's rates line: the held
    controls, or a low-level controller at the physics rate and what it reads."""
    if not isinstance(task.controller, ClosedLoop):
        return "the controls are an open-loop sequence, one per physics step, fixed in advance"
    make = task.controller.low_level
    if make is None:
        return "between two actions the controls they set are held at every physics step"
    controller = call(task, "low_level", make, model, task.parameters({}))
    return (
        f"between two actions a low-level controller (`{type(controller).__name__}`) computes "
        "the controls at every physics step, from the policy's latest action and what MuJoCo "
        f"computes at that step's state: {low_level_reads_text(controller.reads)}"
    )


def low_level_reads_text(reads) -> str:
    """What a low-level controller reads (`mjtrial.sim.low_level.Reads`), in words."""
    parts = ["the joint positions and velocities"]
    if reads.sites:
        parts.append(f"the pose and Jacobian of site {', '.join(f'`{s}`' for s in reads.sites)}")
    if reads.bodies:
        parts.append(
            f"the pose and Jacobian of body {', '.join(f'`{b}`' for b in reads.bodies)}"
        )
    if reads.mass_matrix:
        parts.append("the mass matrix")
    if reads.bias:
        parts.append("the bias forces (gravity, Coriolis, centrifugal)")
    if reads.actuator_length:
        parts.append("the actuators' lengths")
    return ", ".join(parts[:-1]) + " and " + parts[-1]


def _nominal_start(model: mujoco.MjModel, task: Task) -> mujoco.MjModel:
    """The nominal episode's own model as it starts: a task's `episode_setup` may edit it (a
    weld's relative pose and torque scale), and that is what acts, not the compiled model."""
    if task.episode_setup is None:
        return model
    values = {p.name: p.nominal_value for p in task.state_parameters}
    start, _ = BoundTask.of(task, model).episode(values, scratch=mujoco.MjData(model))
    return start


def _hz(period: float) -> str:
    return f"{period * 1e3:.4g} ms, {1.0 / period:.4g} Hz"


def _rate_lines(
    model: mujoco.MjModel, task: Task, config: Mapping[str, Any], model_file: Path
) -> list[str]:
    """The physics' and the policy's rates under each condition (its own model where it edits
    it: another timestep), the sensing latency, and what acts between two actions."""
    controller = task.controller
    groups: dict[tuple[float, int, int], list[str]] = {}
    for name, condition in config["conditions"].items():
        own = model
        if model_edits(condition):
            own = condition_model(config_slice("rollout", config, condition=name), model_file)
        step, latency = 1, 0
        if isinstance(controller, ClosedLoop):
            timing = call(task, "timing", controller.timing, own, task.parameters(condition))
            step, latency = timing.steps_per_control, timing.latency_steps
        groups.setdefault((float(own.opt.timestep), step, latency), []).append(name)
    lines = []
    for (dt, step, latency), names in groups.items():
        which = "" if len(groups) == 1 else f" under {', '.join(f'`{n}`' for n in names)}"
        text = f"- Rates{which}: the physics steps every {_hz(dt)}"
        if isinstance(controller, ClosedLoop):
            text += f"; the policy acts every {step} physics steps ({_hz(step * dt)})"
            if latency:
                text += (
                    f" on observations {latency} physics steps ({latency * dt * 1e3:.4g} ms) old"
                )
        lines.append(f"{text}; {between_actions_text(task, model)}.")
    return lines


def _controller_lines(
    model: mujoco.MjModel, task: Task, conditions: Mapping[str, Any], repo_root: Path
) -> list[str]:
    """What the policy's output columns drive under each condition (a condition's policy file
    maps them by its own contract), and how each episode starts when the task's
    `episode_setup` (a suite's own reset) prepares it."""
    lines = []
    if isinstance(task.controller, ClosedLoop):
        groups: dict[tuple[Any, str], list[str]] = {}
        for name, condition in conditions.items():
            groups.setdefault(_condition_actions(task, condition, repo_root), []).append(name)
        for (actions, scaling), names in groups.items():
            if not actions:
                continue
            which = "" if len(groups) == 1 else f" under {', '.join(f'`{n}`' for n in names)}"
            title = f"- The policy's output columns{which}, in order" + (
                f" ({scaling}):" if scaling else ":"
            )
            lines += action_lines(model, bind_actions(model, actions), title=title)
    if task.episode_setup is not None:
        doc = (task.episode_setup.__doc__ or "").strip().split("\n\n")[0]
        what = " ".join(doc.split()) or "(no docstring)"
        lines.append(
            f"- Each episode starts from the task's `episode_setup`, run after the reset: {what}"
        )
    return lines


def _contact_edit_lines(
    config: Mapping[str, Any], model: mujoco.MjModel, model_path: Path, task: Task
) -> list[str]:
    """What each condition's edits and each state parameter (from its low to its high value)
    do to the contacts, in MuJoCo's mixed terms (`contacts.describe_contact_changes`): a geom's
    own friction is not its contacts'. None where no geom's contact parameters are edited."""
    lines = []
    for name, condition in config["conditions"].items():
        edits = model_edits(condition)
        if edits:
            key = f"conditions.{name}.model"
            edited, _ = variant_model(model_path, {}, key_prefix=key, then=[(edits, key)])
            lines += [f"- condition `{name}`: {line}" for line in _contact_changes(model, edited)]
    bound = BoundTask.of(task, model)
    nominal = {p.name: p.nominal_value for p in task.state_parameters}
    scratch = mujoco.MjData(model)
    for p in task.state_parameters:
        if p.apply.stage != "model":
            continue
        low, high = (
            bound.episode(nominal | {p.name: v}, scratch=scratch)[0] for v in (p.low, p.high)
        )
        lines += [
            f"- state parameter `{p.name}` from {p.low:g} to {p.high:g}: {line}"
            for line in _contact_changes(low, high)
        ]
    if not lines:
        return []
    return [
        "",
        "What the edits of geoms do to their contacts (MuJoCo mixes each pair's parameters "
        "from its two geoms, as in the contacts table above):",
        "",
        *lines,
    ]


def _contact_changes(before: mujoco.MjModel, after: mujoco.MjModel) -> list[str]:
    return describe_contact_changes(before, after) if before.ngeom == after.ngeom else []


def setup_section(
    summary: Mapping[str, Any],
    config: Mapping[str, Any],
    manifest: Mapping[str, Any],
    model: mujoco.MjModel,
    task: Task,
    repo_root: Path,
) -> list[str]:
    """The report's Setup section: the simulator, task and model, the solver, what bounds each
    actuator, the rates, what the policy's columns drive under each condition, joints and
    contacts, the conditions, how the initial states were drawn, and the sample size."""
    m = manifest["model"]
    states = config["states"]
    bitgen = type(np.random.default_rng(0).bit_generator).__name__
    lines = [
        "## Setup",
        "",
        f"- Simulator: MuJoCo {manifest['versions']['mujoco']}.",
        *_task_lines(manifest.get("task")),
        f"- Model: `{m['path']}`, sha256 `{m['sha256']}` {model_files_text(m.get('files'))}.",
        solver_line(m, model, task.controller),
        *actuator_lines(model, keyframe=task.keyframe),
        *equality_lines(_nominal_start(model, task), after_setup=task.episode_setup is not None),
        *_rate_lines(model, task, config, repo_root / m["path"]),
        *_controller_lines(model, task, config["conditions"], repo_root),
        *joint_lines(model),
        *contact_lines(model),
        "",
        "Conditions (each evaluation state runs under every condition: a paired design):",
        "",
        *markdown_table(
            ["condition", "setting"],
            [
                [name, setting(condition_record(task, c), task)]
                for name, c in config["conditions"].items()
            ],
        ),
        *_contact_edit_lines(config, model, repo_root / m["path"], task),
        "",
        *_initial_states_lines(states, task, bitgen),
        *(
            [
                "",
                "Only states the task's `valid_state` accepts were kept: the draw was repeated "
                "from the same generator in rounds and the valid states kept in draw order "
                "(`mjtrial.design.states.draw_valid_states`); "
                + _redrawn_text(manifest.get("states_redrawn")),
            ]
            if task.valid_state is not None
            else []
        ),
        "",
        f"Development states came from a different seed, {states['development_seed']}"
        + _development_use(config)
        + "; the states stage refuses a configuration whose development and evaluation states "
        "share a state, and evaluation states a pilot of this experiment ran on (whatever the "
        "seeds say since), so no reported number comes from a tuning state.",
    ]
    plan = summary.get("sample_size")
    if plan:
        met = "met" if plan["met"] else "**not met**"
        lines += [
            "",
            f"Sample size: n = {plan['n']}; the design's plan needs {plan['required']} states for "
            f"a {pct(summary['confidence'])} half-width of {plan['target_halfwidth']:g} at worst"
            f": {met}.",
        ]
    return lines
