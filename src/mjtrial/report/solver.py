"""What the report says of MuJoCo's solver and the medium: read from the compiled model's
`opt`, and the warm-start rule as the engine runs it."""

from __future__ import annotations

from typing import Any

import mujoco

from mjtrial.task import OpenLoop

_SOLVER_NAMES = {  # as MJCF spells them (`<option solver=...>`)
    mujoco.mjtSolver.mjSOL_PGS: "PGS",
    mujoco.mjtSolver.mjSOL_CG: "CG",
    mujoco.mjtSolver.mjSOL_NEWTON: "Newton",
}


def warm_start_rule(controller: Any, model: mujoco.MjModel) -> str:
    """How the constraint solver's warm start is carried, as this engine runs an episode: an
    open-loop episode is one `mujoco.rollout` call, a closed-loop one a call per control step,
    and `mujoco.rollout` sets the warm start to zero at each call (`mjtrial.sim.closed_loop`)."""
    if model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_WARMSTART:
        return 'warm start disabled by the model (`<flag warmstart="disable"/>`)'
    if isinstance(controller, OpenLoop):
        return (
            "warm start zero at each episode's start, then carried from step to step (one "
            "`mujoco.rollout` call per episode)"
        )
    if getattr(controller, "low_level", None) is not None:
        return (
            "warm start zero at each episode's start, then carried from step to step (each "
            "episode keeps its `MjData`, stepped by `mj_step1` and `mj_step2` around its "
            "low-level controller), as a suite's own loop carries it"
        )
    if getattr(controller, "carry_warmstart", False):
        return (
            "warm start zero at each episode's start, then carried from step to step and "
            "across control instants (`mujoco.rollout`'s `initial_warmstart`), as a suite's "
            "own loop carries it"
        )
    return (
        "warm start set to zero at each control instant (`mujoco.rollout` zeros it at each "
        "call, one call per control step) and carried between the physics steps of one; a "
        "suite's own loop carries it across control instants too, which moves the last bits of "
        "an episode with a contact or an equality active"
    )


def medium_text(model: mujoco.MjModel) -> str:
    """The fluid the bodies move through (`density`, `viscosity`, `wind`), "" when there is
    none: MuJoCo then applies drag and viscous forces to every body."""
    opt = model.opt
    if not (opt.density or opt.viscosity or opt.wind.any()):
        return ""
    wind = ", ".join(f"{v:g}" for v in opt.wind)
    ellipsoids = int((model.geom_fluid[:, 0] > 0).sum())
    shape = (
        f'; {ellipsoids} geoms with `fluidshape="ellipsoid"` use the ellipsoid model'
        if ellipsoids
        else ""
    )
    return (
        f"medium: `density` {opt.density:g} kg/m³, `viscosity` {opt.viscosity:g} Pa·s, `wind` "
        f"({wind}) m/s: MuJoCo applies its drag and viscous forces to every body (the "
        f"inertia-box model{shape})"
    )


def solver_line(manifest_model: dict[str, Any], model: mujoco.MjModel, controller: Any) -> str:
    """The setup's solver line: the integration (timestep, integrator, from the manifest), the
    constraint solver (solver, iterations, tolerance, its line search, noslip), the friction
    cone and impratio, the warm-start rule and the medium."""
    opt = model.opt
    solver = _SOLVER_NAMES[mujoco.mjtSolver(opt.solver)]
    parts = [
        f"timestep {manifest_model['timestep']:g} s, integrator {manifest_model['integrator']}",
        f"constraint solver {solver}, at most {opt.iterations} iterations, tolerance "
        f"{opt.tolerance:g}"
        + (
            f" (line search at most {opt.ls_iterations} iterations, tolerance {opt.ls_tolerance:g})"
            if solver != "PGS"
            else ""
        ),
        f"friction cone {manifest_model['cone']}, impratio {manifest_model['impratio']:g}",
    ]
    if opt.noslip_iterations:
        parts.append(
            f"noslip solver: {opt.noslip_iterations} iterations, tolerance {opt.noslip_tolerance:g}"
        )
    parts.append(warm_start_rule(controller, model))
    if medium := medium_text(model):
        parts.append(medium)
    return f"- Solver: {'; '.join(parts)}."
