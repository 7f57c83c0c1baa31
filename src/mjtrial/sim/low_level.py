"""A controller at the physics rate, between the policy and the actuators.

robosuite (and LIBERO, RoboCasa, MimicGen above it) drives an arm through an operational-space
controller: the policy acts at 20 Hz, and at every 2 ms physics step the controller recomputes
the joint torques from the current site Jacobian, mass matrix and bias forces. Such a controller
cannot go to `mujoco.rollout` (no callback runs between its steps), and called as a policy at
every step it cost a Python call, a private `MjData` and the policy's replay per step and episode.

Here a batch's episodes step together, one physics step at a time: `mj_step1` on each episode's
own data (MuJoCo releases the interpreter lock, so the episodes of a slice run on a thread while
another slice runs on another), what the controller reads gathered into batch arrays
(`PhysicsView`), the controller called once on the whole slice, then `mj_step2` on each. An
episode's result is that of the plain loop a user writes, `mj_step1`, the controller on that
episode alone, `mj_step2` (`reference_episode`), bit for bit, whatever the batch or the threads:
each episode has its own `MjData` from its start to its end, so the solver's warm start is
carried from step to step as in that loop and in robosuite's own (the lockstep engine's
`mujoco.rollout` blocks start each control period from a zero warm start instead), and the
controller must compute each row from that row alone (the config check runs it alone and in a
batch: `check_rows_alone`).

Like `mujoco.rollout`, an episode stops at its first MuJoCo warning and repeats its frozen state.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import mujoco
import numpy as np

from mjtrial.sim.physics import FULLPHYSICS


@dataclass(frozen=True)
class Reads:
    """What a low-level controller reads at each physics step besides the time, qpos and qvel
    (gathered only when asked for: each costs a MuJoCo call per episode and step).

    Attributes:
      sites: sites whose pose (`site_xpos`, `site_xmat`) and Jacobian (`mj_jacSite`) it reads.
      bodies: bodies whose pose (`xpos`, `xquat`) and Jacobian (`mj_jacBody`) it reads.
      mass_matrix: the dense joint-space inertia matrix (`mj_fullM`).
      bias: `qfrc_bias`, the Coriolis, centrifugal and gravity forces.
      actuator_length: `actuator_length`.
    """

    sites: tuple[str, ...] = ()
    bodies: tuple[str, ...] = ()
    mass_matrix: bool = False
    bias: bool = False
    actuator_length: bool = False


@dataclass(frozen=True)
class PhysicsView:
    """What MuJoCo computed at the current state of each episode of a batch (after `mj_step1`:
    positions and velocities, before the controls act). Row i is episode i. The arrays are the
    engine's buffers, overwritten at the next step: copy what you keep.

    Attributes:
      time: (n,) simulation time (s).
      qpos: (n, nq); qvel: (n, nv).
      site_xpos: (n, n_sites, 3); site_xmat: (n, n_sites, 9) row-major rotation matrices.
      site_jacp: (n, n_sites, 3, nv) translational, site_jacr: (n, n_sites, 3, nv) rotational
        Jacobians of `Reads.sites`, in their order.
      body_xpos: (n, n_bodies, 3); body_xquat: (n, n_bodies, 4) w-x-y-z;
      body_jacp, body_jacr: (n, n_bodies, 3, nv) of `Reads.bodies`.
      mass_matrix: (n, nv, nv) or None; bias: (n, nv) or None; actuator_length: (n, nu) or None.
    """

    time: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    site_xpos: np.ndarray
    site_xmat: np.ndarray
    site_jacp: np.ndarray
    site_jacr: np.ndarray
    body_xpos: np.ndarray
    body_xquat: np.ndarray
    body_jacp: np.ndarray
    body_jacr: np.ndarray
    mass_matrix: np.ndarray | None
    bias: np.ndarray | None
    actuator_length: np.ndarray | None

    @classmethod
    def empty(cls, model: mujoco.MjModel, reads: Reads, n: int) -> PhysicsView:
        ns, nb, nv = len(reads.sites), len(reads.bodies), model.nv
        return cls(
            time=np.zeros(n),
            qpos=np.zeros((n, model.nq)),
            qvel=np.zeros((n, nv)),
            site_xpos=np.zeros((n, ns, 3)),
            site_xmat=np.zeros((n, ns, 9)),
            site_jacp=np.zeros((n, ns, 3, nv)),
            site_jacr=np.zeros((n, ns, 3, nv)),
            body_xpos=np.zeros((n, nb, 3)),
            body_xquat=np.zeros((n, nb, 4)),
            body_jacp=np.zeros((n, nb, 3, nv)),
            body_jacr=np.zeros((n, nb, 3, nv)),
            mass_matrix=np.zeros((n, nv, nv)) if reads.mass_matrix else None,
            bias=np.zeros((n, nv)) if reads.bias else None,
            actuator_length=np.zeros((n, model.nu)) if reads.actuator_length else None,
        )


def view_rows(view: PhysicsView, rows: slice) -> PhysicsView:
    """A copy of some rows of a view."""
    return PhysicsView(
        **{
            name: None if value is None else value[rows].copy()
            for name, value in vars(view).items()
        }
    )


class LowLevelController(Protocol):
    """A controller called at every physics step on a batch of episodes. Row i of every array
    is episode i; each row must be computed from that row alone.

    Attributes:
      reads: what it reads (`Reads`).
      n_inputs: the number of the policy's output columns it takes (its action's size).
    """

    reads: Reads
    n_inputs: int

    def reset(self, models: Sequence[mujoco.MjModel]) -> None:
        """Start new episodes, one per model (each episode's own: a condition's or a state
        parameter's edit included); clear any per-episode state (interpolators, goals)."""

    def __call__(self, view: PhysicsView, action: np.ndarray, new_action: bool) -> np.ndarray:
        """The controls (n, nu) at this physics step.

        Args:
          view: what MuJoCo computed at the current state (`PhysicsView`).
          action: (n, n_inputs) the policy's latest action.
          new_action: True at the first physics step after the policy acted (a goal is set
            from the action then, as robosuite's `set_goal`).
        """


MakeController = Callable[[], LowLevelController]
"""Builds a fresh controller (one per slice of a batch: each keeps its rows' state)."""


class ControllerError(ValueError):
    """The controller returned something the engine cannot apply (shape, non-finite values)."""


def check_model(model: mujoco.MjModel) -> None:
    """Refuse a model whose `mj_step` is not `mj_step1` then `mj_step2`: MuJoCo's RK4 integrator
    steps in one call, so a controller cannot act between the two halves."""
    if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
        raise ControllerError(
            "a low-level controller needs the Euler or an implicit integrator (mj_step1 and "
            "mj_step2); the model uses RK4"
        )


def _ids(model: mujoco.MjModel, kind: mujoco.mjtObj, names: Sequence[str]) -> list[int]:
    out = []
    for name in names:
        i = mujoco.mj_name2id(model, kind, name)
        if i < 0:
            raise ControllerError(
                f"the controller reads {kind.name[6:].lower()} {name!r}: no "
                "such element in the model"
            )
        out.append(i)
    return out


def jacobian_is_zero(model: mujoco.MjModel, body: int) -> bool:
    """`mj_jac` of a body whose weld root has no dofs only clears its outputs (no joint
    between it and the world): the view's zeros are that Jacobian, at every step."""
    return model.body_dofnum[model.body_weldid[body]] == 0


def _pose_is_fixed(model: mujoco.MjModel, body: int) -> bool:
    """No joint and no mocap body between the body and the world: the kinematics give it the
    same pose, bit for bit, at every step (from the model's constants alone)."""
    while body > 0:
        if model.body_jntnum[body] or model.body_mocapid[body] >= 0:
            return False
        body = model.body_parentid[body]
    return True


def _place(m, body: int, pose: list, jacobian: tuple, *, fixed: list, copies: list, calls: list):
    """A site's or body's reads: its pose into `fixed` (read once) if its body cannot move, else
    into `copies` (each step); its Jacobian call into `calls` unless it is always zero."""
    (fixed if _pose_is_fixed(m, body) else copies).extend(pose)
    if not jacobian_is_zero(m, body):
        calls.append(jacobian)


class _Gather:
    """Fills a `PhysicsView`'s rows from the episodes' data after `mj_step1`. Each row's
    (view, data) array pairs and MuJoCo calls are made once: MjData's arrays are views of its
    buffers, so a step costs a copy per field, not an attribute lookup and a new view each
    (a third of the Panda's per-episode step, with the controller, was this bookkeeping).

    Per row and step, `copies` and `calls` leave out what need not be read again: the time,
    qpos and qvel (`state`: the engine has them from the step before), a fixed body's or
    site's pose (`fixed`: read at the first step), and a Jacobian that is zero (never
    computed: the view holds its zeros)."""

    def __init__(self, models, datas, reads: Reads, view: PhysicsView) -> None:
        model = models[0]
        sites = _ids(model, mujoco.mjtObj.mjOBJ_SITE, reads.sites)
        bodies = _ids(model, mujoco.mjtObj.mjOBJ_BODY, reads.bodies)
        self.time = view.time
        self.state: list[list[tuple[np.ndarray, np.ndarray]]] = []
        self.fixed: list[list[tuple[np.ndarray, np.ndarray]]] = []
        self.copies: list[list[tuple[np.ndarray, np.ndarray]]] = []
        self.calls: list[list[tuple[Callable[..., None], tuple]]] = []
        for i, (m, d) in enumerate(zip(models, datas, strict=True)):
            state = [(view.qpos[i], d.qpos), (view.qvel[i], d.qvel)]
            fixed: list[tuple[np.ndarray, np.ndarray]] = []
            copies: list[tuple[np.ndarray, np.ndarray]] = []
            calls: list[tuple[Callable[..., None], tuple]] = []
            place = partial(_place, m, fixed=fixed, copies=copies, calls=calls)
            for k, site in enumerate(sites):
                place(
                    m.site_bodyid[site],
                    [
                        (view.site_xpos[i, k], d.site_xpos[site]),
                        (view.site_xmat[i, k], d.site_xmat[site]),
                    ],
                    (mujoco.mj_jacSite, (m, d, view.site_jacp[i, k], view.site_jacr[i, k], site)),
                )
            for k, body in enumerate(bodies):
                place(
                    body,
                    [(view.body_xpos[i, k], d.xpos[body]), (view.body_xquat[i, k], d.xquat[body])],
                    (mujoco.mj_jacBody, (m, d, view.body_jacp[i, k], view.body_jacr[i, k], body)),
                )
            if reads.mass_matrix:
                calls.append((mujoco.mj_fullM, (m, d, view.mass_matrix[i])))
            if reads.bias:
                copies.append((view.bias[i], d.qfrc_bias))
            if reads.actuator_length:
                copies.append((view.actuator_length[i], d.actuator_length))
            self.state.append(state)
            self.fixed.append(fixed)
            self.copies.append(copies)
            self.calls.append(calls)

    def row(self, i: int, d: mujoco.MjData) -> None:
        """All of row i, from episode data `d` after `mj_step1`."""
        self.state_row(i, d)
        for target, source in self.copies[i]:
            target[...] = source  # a third of np.copyto's call
        for call, args in self.calls[i]:
            call(*args)

    def state_row(self, i: int, d: mujoco.MjData) -> None:
        """Row i's time, qpos, qvel and fixed poses, what `copies` and `calls` leave out."""
        self.time[i] = d.time
        for target, source in self.state[i] + self.fixed[i]:
            target[...] = source


def checked_controls(ctrl: object, n: int, nu: int) -> np.ndarray:
    """The controller's answer as (n, nu) finite floats, else `ControllerError`."""
    ctrl = np.asarray(ctrl, dtype=np.float64)
    if ctrl.shape != (n, nu):
        raise ControllerError(
            f"low-level controller: expected controls of shape ({n}, {nu}), got {ctrl.shape}"
        )
    if not np.isfinite(ctrl).all():
        rows = np.flatnonzero(~np.isfinite(ctrl).all(axis=1))
        raise ControllerError(
            f"low-level controller: non-finite controls for {len(rows)} "
            f"episode(s), e.g. row {rows[0]}"
        )
    return ctrl


def _push_steps(pushes, rows: np.ndarray):
    return (
        None
        if pushes is None
        else (pushes.body, pushes.start[rows], pushes.stop[rows], pushes.wrench[rows])
    )


def _lean_state(model: mujoco.MjModel) -> bool:
    """True when the mjSTATE_FULLPHYSICS state is the time, qpos and qvel alone (no
    activations, history or plugin state) and no tree sleeps (`mj_step1` may wake one): then
    `mj_step1` leaves them as `mj_step2` left them, unless they are bad (`state_is_bad`: it
    resets the data) or a control callback is set (it may write anything)."""
    size = mujoco.mj_stateSize(model, FULLPHYSICS)
    sleep = getattr(mujoco.mjtEnableBit, "mjENBL_SLEEP", 0)
    return size == 1 + model.nq + model.nv and not model.opt.enableflags & sleep


def state_is_bad(state: np.ndarray) -> np.ndarray:
    """(n,) rows of (n, 1 + nq + nv) states whose qpos or qvel `mj_checkPos` / `mj_checkVel`
    call bad (NaN, or beyond mjMAXVAL: 1e10), which makes `mj_step1` reset the data."""
    return ~(np.abs(state[:, 1:]) <= 1e10).all(axis=1)


class _Slice:
    """Some episodes of a batch, stepped together on one thread with one controller.

    Each episode's state after each step (time, qpos, qvel; or `mj_getState`'s where it holds
    more) and sensors go to `state` and `sensors`, rows of the slice, whence whole columns
    of the outputs are written at once, and whence the next step's view takes its time, qpos
    and qvel: `mj_step1` does not change them (`_lean_state`) unless they are bad, and a bad
    row is read from its data instead. A halted episode's rows stay its frozen state."""

    def __init__(self, models, datas, rows, make: MakeController, pushes, initial) -> None:
        self.models, self.datas, self.rows = models, datas, rows
        self.controller = make()
        self.controller.reset(models)
        model = models[0]
        self.view = PhysicsView.empty(model, self.controller.reads, len(rows))
        self.gather = _Gather(models, datas, self.controller.reads, self.view)
        self.halted = np.zeros(len(rows), dtype=bool)
        self.live = [True] * len(rows)  # ~halted, as a list: read per row and step
        self.lean = all(_lean_state(m) for m in models)
        self.state = np.array(initial, dtype=np.float64)
        self.sensors = np.zeros((len(rows), model.nsensordata))
        self.first_step = True
        # the rows of the outputs as a slice where they are contiguous (array_split's are)
        self.out = (
            slice(int(rows[0]), int(rows[-1]) + 1)
            if len(rows) and np.array_equal(rows, np.arange(rows[0], rows[-1] + 1))
            else rows
        )
        nq, nv = model.nq, model.nv
        # per episode, what each half step uses: its model and data, its lean copies and calls
        # after mj_step1; the data's arrays written or read after the controller, and its rows
        # of `state` and `sensors`
        self.before = [
            (m, d, self.gather.copies[i], self.gather.calls[i])
            for i, (m, d) in enumerate(zip(models, datas, strict=True))
        ]
        self.after = [
            (
                m,
                d,
                d.ctrl,
                d.sensordata,
                memoryview(d.warning.number),  # any() over it: a fifth of count_nonzero's call
                d.qpos,
                d.qvel,
                self.state[i],
                self.state[i, 1 : 1 + nq],
                self.state[i, 1 + nq : 1 + nq + nv],
                self.sensors[i],
            )
            for i, (m, d) in enumerate(zip(models, datas, strict=True))
        ]
        self.pushes = _push_steps(pushes, rows)
        self.nu = model.nu

    def block(
        self,
        action: np.ndarray,
        first: int,
        n_steps: int,
        physics: np.ndarray,
        sensordata: np.ndarray,
        applied: np.ndarray,
    ) -> None:
        """Physics steps first .. first + n_steps - 1 of the slice's episodes, the controller
        between `mj_step1` and `mj_step2` of each; writes their rows of the outputs."""
        out, gather, live, view = self.out, self.gather, self.live, self.view
        step1, step2, get_state = mujoco.mj_step1, mujoco.mj_step2, mujoco.mj_getState
        n, nq, nv = len(live), view.qpos.shape[1], view.qvel.shape[1]
        state, lean = self.state, self.lean and mujoco.get_mjcb_control() is None
        pushes = self.pushes
        action = action[self.rows]
        for j in range(first, first + n_steps):
            for i, (m, d, copies, calls) in enumerate(self.before):
                if live[i]:
                    step1(m, d)
                    for target, source in copies:
                        target[...] = source  # a third of np.copyto's call
                    for call, args in calls:
                        call(*args)
            # the rows whose data mj_step1 may not have left at the state recorded, read whole
            whole: Sequence[int] = range(n)
            if lean and not self.first_step:
                # a halted row keeps its stale view, as it keeps its other fields
                rows = slice(None) if all(live) else ~self.halted
                view.time[rows] = state[rows, 0]
                view.qpos[rows] = state[rows, 1 : 1 + nq]
                view.qvel[rows] = state[rows, 1 + nq : 1 + nq + nv]
                fine = np.abs(state[:, 1:]).max() <= 1e10
                whole = () if fine else np.flatnonzero(state_is_bad(state))
            for i in whole:
                if live[i]:
                    gather.state_row(i, self.datas[i])
            self.first_step = False
            with np.errstate(all="ignore"):  # a halted row's stale view is not used
                ctrl = self.controller(view, action, j == first)
            ctrl = np.asarray(ctrl, dtype=np.float64)
            if ctrl.shape != (n, self.nu):
                checked_controls(ctrl, n, self.nu)
            if all(live):
                if not np.isfinite(ctrl).all():
                    checked_controls(ctrl, n, self.nu)
                applied[out, j] = ctrl
            else:
                alive = ~self.halted
                if not np.isfinite(ctrl[alive]).all():
                    checked_controls(ctrl[alive], int(alive.sum()), self.nu)
                # a halted episode repeats its last controls, as its frozen state
                applied[out, j] = np.where(alive[:, None], ctrl, applied[out, j - 1])
            for i, (after, u) in enumerate(zip(self.after, ctrl, strict=True)):
                if live[i]:
                    m, d, d_ctrl, d_sensors, warnings, d_qpos, d_qvel, row, qpos, qvel, sensed = (
                        after
                    )
                    d_ctrl[...] = u
                    if pushes is not None:
                        body, start, stop, wrench = pushes
                        d.xfrc_applied[body] = wrench[i] if start[i] <= j < stop[i] else 0.0
                    step2(m, d)
                    if lean:
                        row[0] = d.time
                        qpos[...] = d_qpos
                        qvel[...] = d_qvel
                    else:
                        get_state(m, d, row, FULLPHYSICS)
                    sensed[...] = d_sensors
                    if any(warnings):
                        live[i] = False
                        self.halted[i] = True
            physics[out, j] = state
            sensordata[out, j] = self.sensors


class Stepper:
    """A batch's episodes stepped by a low-level controller, a control block at a time.

    Args:
      models: one model per episode (the same sizes).
      initial: (n, nstate) mjSTATE_FULLPHYSICS initial states.
      make_controller: builds a controller; one per slice of the batch.
      nthread: threads (0 or 1: the calling thread); the batch is cut into that many slices.
      pushes: a wrench pulse per episode (`closed_loop.Pushes`), or None.
    """

    def __init__(
        self,
        models: Sequence[mujoco.MjModel],
        initial: np.ndarray,
        make_controller: MakeController,
        *,
        nthread: int = 1,
        pushes: Any = None,
    ) -> None:
        for m in models[:1]:
            check_model(m)
        n = len(models)
        datas = []
        for m, state in zip(models, initial, strict=True):
            d = mujoco.MjData(m)
            mujoco.mj_setState(m, d, state, FULLPHYSICS)
            datas.append(d)
        cuts = np.array_split(np.arange(n), max(1, min(nthread, n)))
        self.slices = [
            _Slice(
                [models[i] for i in rows],
                [datas[i] for i in rows],
                rows,
                make_controller,
                pushes,
                initial[rows],
            )
            for rows in cuts
            if len(rows)
        ]
        self.pool = ThreadPoolExecutor(len(self.slices)) if len(self.slices) > 1 else None

    def block(self, action, first, n_steps, physics, sensordata, applied) -> None:
        """Steps first .. first + n_steps - 1 of every episode (see `_Slice.block`)."""
        if self.pool is None:
            self.slices[0].block(action, first, n_steps, physics, sensordata, applied)
            return
        jobs = [
            self.pool.submit(s.block, action, first, n_steps, physics, sensordata, applied)
            for s in self.slices
        ]
        for job in jobs:
            job.result()

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()


class PlainEpisode:
    """One episode in the plain loop a user writes: `mj_step1`, the controller on this episode
    alone, `mj_step2`, on one `MjData` from start to end; stops at the first warning and
    repeats the frozen state. The engine's reference (`closed_loop.reference_episode`).

    Args:
      model: the episode's model (copied); initial: (nstate,) its initial state.
      controller: a fresh controller, reset here for this one episode.
    """

    def __init__(
        self, model: mujoco.MjModel, initial: np.ndarray, controller: LowLevelController
    ) -> None:
        self.m = m = copy.copy(model)
        self.d = d = mujoco.MjData(m)
        mujoco.mj_setState(m, d, initial, FULLPHYSICS)
        check_model(m)
        self.controller = controller
        controller.reset([m])
        self.sites = _ids(m, mujoco.mjtObj.mjOBJ_SITE, controller.reads.sites)
        self.bodies = _ids(m, mujoco.mjtObj.mjOBJ_BODY, controller.reads.bodies)
        self.halted = False
        self.ctrl = np.zeros(m.nu)

    def _view(self) -> PhysicsView:
        m, d, reads, sites, bodies = self.m, self.d, self.controller.reads, self.sites, self.bodies
        jacp, jacr = np.zeros((len(sites), 3, m.nv)), np.zeros((len(sites), 3, m.nv))
        for k, site in enumerate(sites):
            mujoco.mj_jacSite(m, d, jacp[k], jacr[k], site)
        bjacp, bjacr = np.zeros((len(bodies), 3, m.nv)), np.zeros((len(bodies), 3, m.nv))
        for k, body in enumerate(bodies):
            mujoco.mj_jacBody(m, d, bjacp[k], bjacr[k], body)
        mass = None
        if reads.mass_matrix:
            mass = np.zeros((1, m.nv, m.nv))
            mujoco.mj_fullM(m, d, mass[0])
        return PhysicsView(
            time=np.array([d.time]),
            qpos=d.qpos[None].copy(),
            qvel=d.qvel[None].copy(),
            site_xpos=d.site_xpos[sites][None],
            site_xmat=d.site_xmat[sites][None],
            site_jacp=jacp[None],
            site_jacr=jacr[None],
            body_xpos=d.xpos[bodies][None],
            body_xquat=d.xquat[bodies][None],
            body_jacp=bjacp[None],
            body_jacr=bjacr[None],
            mass_matrix=mass,
            bias=d.qfrc_bias[None].copy() if reads.bias else None,
            actuator_length=d.actuator_length[None].copy() if reads.actuator_length else None,
        )

    def step(self, action: np.ndarray, new_action: bool, push: np.ndarray | None, body: int):
        """One physics step under the policy's latest `action` (n_inputs,); `push`: the wrench
        on `body` during this step, or None. Returns (state row, sensordata, ctrl applied)."""
        m, d = self.m, self.d
        if not self.halted:
            mujoco.mj_step1(m, d)
            u = checked_controls(self.controller(self._view(), action[None], new_action), 1, m.nu)
            self.ctrl = u[0]
            d.ctrl[:] = u[0]
            if push is not None:
                d.xfrc_applied[:] = 0.0
                d.xfrc_applied[body] = push
            mujoco.mj_step2(m, d)
            self.halted = any(w.number for w in d.warning)
        row = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
        mujoco.mj_getState(m, d, row, FULLPHYSICS)
        return row, d.sensordata.copy(), self.ctrl.copy()


def check_rows_alone(
    make: MakeController, model: mujoco.MjModel, initial: np.ndarray, *, n_rows: int = 3
) -> None:
    """Raise `ControllerError` unless the controller gives each row alone, from its reset, what
    it gives that row in a batch, bit for bit, over a few steps: an episode's result must not
    depend on its batch (`rollout.shard_size`). The rows are the state `initial` with other
    velocities and actions, what MuJoCo computes there gathered as the engine does."""
    rng = np.random.default_rng(0)
    probe = make()
    view = PhysicsView.empty(model, probe.reads, n_rows)
    datas = [mujoco.MjData(model) for _ in range(n_rows)]
    gather = _Gather([model] * n_rows, datas, probe.reads, view)
    for i, data in enumerate(datas):
        mujoco.mj_setState(model, data, initial, FULLPHYSICS)
        data.qvel[:] += rng.normal(scale=0.1, size=model.nv)
        mujoco.mj_step1(model, data)
        gather.row(i, data)
    actions = rng.uniform(-1.0, 1.0, size=(4, n_rows, probe.n_inputs))
    probe.reset([model] * n_rows)
    together = [
        checked_controls(probe(view, a, k % 2 == 0), n_rows, model.nu)
        for k, a in enumerate(actions)
    ]
    for i in range(n_rows):
        alone = make()
        alone.reset([model])
        row = view_rows(view, slice(i, i + 1))
        for k, a in enumerate(actions):
            ctrl = checked_controls(alone(row, a[i : i + 1], k % 2 == 0), 1, model.nu)
            if not np.array_equal(ctrl[0], together[k][i]):
                diff = float(np.max(np.abs(ctrl[0] - together[k][i])))
                raise ControllerError(
                    f"low-level controller: row {i} alone gives other controls than in a batch "
                    f"of {n_rows} at its call {k} (largest difference {diff:.3g}); compute each "
                    "row from that row alone"
                )
