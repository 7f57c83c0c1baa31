"""Mocap actions: gymnasium-robotics' Fetch arm driven through its mocap weld by the closed-loop
engine equals a plain `mj_step` loop written here that sets `data.mocap_pos` the suite's way
(`mocap_set_action`, `ctrl_set_action` in gymnasium_robotics/utils/mujoco_utils.py), bit for
bit, whatever the batch and the threads; a Metaworld-style target clipped to a box; bad
declarations named in one line.

Warm start: the weld is always active, so the constraint solver's result depends on the warm
start MuJoCo carries between steps. `mujoco.rollout` sets it to zero at every call, that is at
every control instant of the engine; the plain loop here does the same
(`data.qacc_warmstart[:] = 0` before each control block) so the comparison is exact. A loop
that carries it differs in the last bits (about 4e-14 here), which says nothing about the
actions.

The welded body's pose is read as the suite reads it: `data.xpos` as the last `mj_step` left it
(the pose of the state one physics step before the control instant; after the reset's
`mj_forward`, the initial state's).
"""

from __future__ import annotations

import copy
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import REPO_ROOT
from mujoco import rollout

from mjtrial.sim.closed_loop import Timing, reference_episode, run_batch
from mjtrial.sim.physics import FULLPHYSICS
from mjtrial.task import Control, MocapAction, TaskError
from mjtrial.task.actions import bind_actions

FETCH = REPO_ROOT / "tasks" / "fetch_pick" / "assets" / "fetch" / "pick_and_place.xml"
NOMINAL = mujoco.MjModel.from_xml_path(str(FETCH))
GRIPPER = NOMINAL.body("robot0:gripper_link").id
MOCAP_BODY = NOMINAL.body("robot0:mocap").id
OBJECT = NOMINAL.joint("object0:joint").qposadr[0]
FINGERS = ("robot0:l_gripper_finger_joint", "robot0:r_gripper_finger_joint")
SUBSTEPS = 20  # Fetch's n_substeps
FETCH_ACTIONS = (
    # pos_ctrl *= 0.05 after the action is clipped to [-1, 1]; rot_ctrl [1, 0, 1, 0] added
    MocapAction(
        "robot0:mocap",
        relative_to="body",
        scale=0.05,
        max_step=0.05,
        orientation_offset=(1.0, 0.0, 1.0, 0.0),
    ),
    Control(FINGERS, relative=True),  # both fingers' servos at their qpos + action[3]
)


def _episode(dx: float, dy: float) -> tuple[mujoco.MjModel, np.ndarray]:
    """The suite's reset: welds to identity (`reset_mocap_welds`), the mocap on the gripper
    (`reset_mocap2body_xpos`), here kept in the episode's model (every reset takes the mocap
    pose from it); the object moved by (dx, dy)."""
    m = copy.copy(NOMINAL)
    d = mujoco.MjData(m)
    m.eq_data[0, :7] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    d.qpos[OBJECT : OBJECT + 2] += [dx, dy]
    mujoco.mj_forward(m, d)
    m.body_pos[MOCAP_BODY] = d.xpos[GRIPPER]
    m.body_quat[MOCAP_BODY] = d.xquat[GRIPPER]
    state = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
    mujoco.mj_getState(m, d, state, FULLPHYSICS)
    return m, state


OFFSETS = [(0.0, 0.0), (0.05, -0.03), (-0.04, 0.02), (0.02, 0.06), (-0.06, -0.01)]


def _observe(states: np.ndarray) -> np.ndarray:
    return states[:, 1 + OBJECT : 1 + OBJECT + 3]  # the object's position


class Wiggle:
    """Elementwise (so batch-independent) actions of 4 columns, some beyond [-1, 1]."""

    def reset(self, n: int) -> None:
        self.k = 0

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self.k += 1
        x, y, z = obs.T
        return np.stack(
            [2.0 * np.sin(7 * x + self.k), np.cos(5 * y + self.k), np.sin(3 * z) - 0.5, np.sin(x)],
            axis=1,
        )


def _plain_loop(
    m: mujoco.MjModel, initial: np.ndarray, n_controls: int, *, carry: bool = False
) -> np.ndarray:
    """Fetch's step written out: the action, then 20 mj_steps (n_steps, nstate); the warm
    start zeroed at each action (as `mujoco.rollout` starts each call), or carried (`carry`:
    as the suite's own loop does)."""
    d = mujoco.MjData(m)
    mujoco.mj_setState(m, d, initial, FULLPHYSICS)
    mujoco.mj_forward(m, d)  # the suite's reset ends so
    policy, rows = Wiggle(), []
    policy.reset(1)
    state = initial
    for _ in range(n_controls):
        action = np.clip(policy(_observe(state[None]))[0], -1.0, 1.0)
        if not carry:
            d.qacc_warmstart[:] = 0.0  # as mujoco.rollout starts each call
        for i in range(m.nu):  # ctrl_set_action: a position servo's target relative to qpos
            d.ctrl[i] = d.qpos[m.jnt_qposadr[m.actuator_trnid[i, 0]]] + action[3]
        # mocap_set_action: reset_mocap2body_xpos, then the deltas added
        d.mocap_pos[0] = d.xpos[GRIPPER] + action[:3] * 0.05
        d.mocap_quat[0] = d.xquat[GRIPPER] + np.array([1.0, 0.0, 1.0, 0.0])
        for _ in range(SUBSTEPS):
            mujoco.mj_step(m, d)
            state = np.empty(len(initial))
            mujoco.mj_getState(m, d, state, FULLPHYSICS)
            rows.append(state)
    return np.stack(rows)


def _engine(episodes, timing, *, nthread: int, split: list[int], carry: bool = False):
    actuation = bind_actions(NOMINAL, FETCH_ACTIONS)
    models = [m for m, _ in episodes]
    initial = np.stack([s for _, s in episodes])
    out = []
    with rollout.Rollout(nthread=nthread) as runner:
        datas = [mujoco.MjData(NOMINAL) for _ in range(max(1, nthread))]
        for rows in np.split(np.arange(len(models)), split):
            out.append(
                run_batch(
                    [models[i] for i in rows],
                    initial[rows],
                    Wiggle(),
                    _observe,
                    timing,
                    runner=runner,
                    datas=datas,
                    actuation=actuation,
                    carry_warmstart=carry,
                )
            )
    return (
        np.concatenate([b.physics for b in out]),
        np.concatenate([b.ctrl for b in out]),
        np.concatenate([b.mocap for b in out]),
    )


@pytest.fixture(scope="module")
def episodes():
    return [_episode(dx, dy) for dx, dy in OFFSETS]


TIMING = Timing(SUBSTEPS, 12)


def test_fetch_through_the_engine_equals_a_plain_loop_setting_mocap_pos(episodes):
    physics, ctrl, mocap = _engine(episodes, TIMING, nthread=0, split=[])
    for i, (m, initial) in enumerate(episodes):
        np.testing.assert_array_equal(physics[i], _plain_loop(m, initial, TIMING.n_controls))
        ref = reference_episode(
            m, initial, Wiggle(), _observe, TIMING, actuation=bind_actions(NOMINAL, FETCH_ACTIONS)
        )
        np.testing.assert_array_equal(physics[i], ref.physics[0])
        np.testing.assert_array_equal(mocap[i], ref.mocap[0])
        np.testing.assert_array_equal(ctrl[i], ref.ctrl[0])
    # the arm moves: the gripper's target wanders, and the fingers' servos follow their joints
    assert np.ptp(mocap[:, :, 0, :3], axis=1).min() > 0.01
    assert not np.array_equal(ctrl[:, :, 0], ctrl[:, :, 1])


def test_a_carried_warm_start_equals_the_suites_own_loop(episodes):
    """`carry_warmstart`: the engine's episodes equal the plain loop that never resets the warm
    start, whatever the batch and threads, and differ from those of a zeroed one (the weld and
    the contacts are active, so the solver's start matters)."""
    physics, _, _ = _engine(episodes, TIMING, nthread=0, split=[], carry=True)
    zeroed, _, _ = _engine(episodes, TIMING, nthread=0, split=[])
    for i, (m, initial) in enumerate(episodes):
        carried = _plain_loop(m, initial, TIMING.n_controls, carry=True)
        np.testing.assert_array_equal(physics[i], carried)
        ref = reference_episode(
            m,
            initial,
            Wiggle(),
            _observe,
            TIMING,
            actuation=bind_actions(NOMINAL, FETCH_ACTIONS),
            carry_warmstart=True,
        )
        np.testing.assert_array_equal(physics[i], ref.physics[0])
    assert not np.array_equal(physics, zeroed)
    split, _, _ = _engine(episodes, TIMING, nthread=2, split=[2], carry=True)
    np.testing.assert_array_equal(split, physics)


def test_batches_and_threads_do_not_change_the_fetch_episodes(episodes):
    whole = _engine(episodes, TIMING, nthread=0, split=[])
    for nthread, split in ((2, [2]), (1, [1, 4])):
        for a, b in zip(
            whole, _engine(episodes, TIMING, nthread=nthread, split=split), strict=True
        ):
            np.testing.assert_array_equal(a, b)


def test_a_target_relative_to_the_last_is_clipped_to_its_box():
    """Metaworld: new = mocap_pos + action / 100, clipped to mocap_low..mocap_high."""
    low, high = np.array([1.2, 0.6, 0.4]), np.array([1.45, 0.9, 0.7])
    action = MocapAction(
        "robot0:mocap", relative_to="target", scale=0.01, low=tuple(low), high=tuple(high)
    )
    actuation = bind_actions(NOMINAL, (action,))
    targets = np.array([[[1.44, 0.61, 0.5, 1.0, 0.0, 0.0, 0.0]]] * 2)
    outputs = np.array([[3.0, -2.0, 1.0], [-1.0, 1.0, 0.5]])
    ctrl, new = actuation.apply(outputs, np.zeros((2, NOMINAL.nq)), targets)
    expected = np.clip(targets[:, 0, :3] + outputs / 100, low, high)
    np.testing.assert_array_equal(new[:, 0, :3], expected)
    np.testing.assert_array_equal(new[:, 0, 3:], targets[:, 0, 3:])
    np.testing.assert_array_equal(ctrl, np.zeros((2, NOMINAL.nu)))  # no Control: ctrl 0
    assert new[0, 0, 0] == high[0] and new[0, 0, 1] == low[1]  # the box bit


@pytest.mark.parametrize(
    "actions, message",
    [
        (
            (MocapAction("robot0:gripper_link"),),
            "actions[0]: expected body 'robot0:gripper_link' to be a mocap body",
        ),
        ((Control("nope"),), "actions[0]: "),
        (
            (Control(FINGERS[0]), Control(FINGERS)),
            "actions[1]: actuator 'robot0:l_gripper_finger_joint' is driven by actions[0] too",
        ),
        (
            (MocapAction("robot0:mocap", max_step=0.1),),
            "max_step: expected a number > 0 with a relative action",
        ),
        (
            (MocapAction("robot0:mocap", orientation_offset=(1, 0, 0, 0)),),
            'orientation_offset: expected relative_to="body"',
        ),
    ],
)
def test_bad_actions_are_named(actions, message):
    with pytest.raises(TaskError) as err:
        bind_actions(NOMINAL, actions)
    assert message in str(err.value) and "\n" not in str(err.value)


# --------------------------------------------------------------------------------------------
# A policy file whose output drives both fingers from one column and the mocap from three
# --------------------------------------------------------------------------------------------

MOCAP_ENTRY = {
    "body": "robot0:mocap",
    "relative_to": "body",
    "scale": 0.05,
    "max_step": 0.05,
    "orientation_offset": [1.0, 0.0, 1.0, 0.0],
}


class SessionPolicy:
    """The graph run by hand: what the contract says, written without it (the gripper's
    column onto the fingers' shared ctrlrange [0, 0.2], clipped; the mocap columns as given)."""

    def __init__(self, session) -> None:
        self.session = session

    def reset(self, n: int) -> None:
        pass

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        [action] = self.session.run(["action"], {"observations": obs.astype(np.float32)})
        action = action.astype(np.float64)
        low, high = NOMINAL.actuator_ctrlrange[0]
        grip = np.clip(low + (action[:, :1] + 1.0) * (high - low) / 2.0, low, high)
        return np.concatenate([grip, action[:, 1:]], axis=1)


def fetch_by_file_and_by_hand(tmp_path, *, seed, fingers_entry, fingers, policy_class):
    """The Fetch driven by a policy file (a tanh MLP whose contract maps its fingers' column
    as `fingers_entry` and three columns to the mocap), and by the same graph run by hand
    (`policy_class`) through the task's own `fingers` control and mocap action, on three
    states. Returns (the task, its controller by hand, run, the two batches' episodes)."""
    import dataclasses

    from fetch_mocap import fetch_task
    from policy_graphs import tanh_mlp, write

    from mjtrial.policy_files.file import load_policy_file, policy_task
    from mjtrial.sim.engine import iter_batches
    from mjtrial.task import BoundTask

    path = write(
        tmp_path,
        "fetch",
        tanh_mlp([2, 16, 4], seed=seed),
        task="fetch_mocap",
        observations=["object_x", "object_y"],
        actuators=[fingers_entry],
        mocap=[MOCAP_ENTRY],
        control_period=0.04,
    )
    task = fetch_task()
    policy_file = load_policy_file(path, task)
    values = {
        "state_id": np.arange(3),
        "object_dx": np.array([0.0, 0.05, -0.08]),
        "object_dy": np.array([0.03, -0.06, 0.0]),
    }
    run = lambda t: next(iter_batches(BoundTask.of(t), values, {}, thresholds={}, nthread=1))  # noqa: E731
    by_file = run(policy_task(task, policy_file)).episodes
    controller = dataclasses.replace(
        task.controller,
        policy=lambda model, params: policy_class(policy_file.session),
        actions=(
            fingers,
            MocapAction(
                "robot0:mocap",
                relative_to="body",
                scale=0.05,
                max_step=0.05,
                orientation_offset=(1.0, 0.0, 1.0, 0.0),
            ),
        ),
    )
    by_hand = run(dataclasses.replace(task, controller=controller)).episodes
    return task, controller, run, by_file, by_hand


def test_a_policy_file_drives_both_fingers_from_one_column_and_the_mocap(tmp_path):
    _, _, _, by_file, by_hand = fetch_by_file_and_by_hand(
        tmp_path,
        seed=3,
        fingers_entry=list(FINGERS),
        fingers=Control(FINGERS),
        policy_class=SessionPolicy,
    )
    np.testing.assert_array_equal(by_file.physics, by_hand.physics)
    np.testing.assert_array_equal(by_file.mocap, by_hand.mocap)
    np.testing.assert_array_equal(by_file.ctrl[..., 0], by_file.ctrl[..., 1])  # one column
    assert np.ptp(by_file.mocap[:, :, 0, :3], axis=1).max() > 0.01  # the arm was moved


def test_a_contract_column_over_actuators_of_different_ranges_is_refused(tmp_path):
    from fetch_mocap import fetch_task
    from policy_graphs import tanh_mlp, write

    from mjtrial.policy_files.file import PolicyFileError, load_policy_file
    from mjtrial.task import TaskError

    task = fetch_task()
    model = mujoco.MjModel.from_xml_path(str(FETCH))
    model.actuator_ctrlrange[1] = [0.0, 0.1]
    path = write(
        tmp_path,
        "fetch",
        tanh_mlp([2, 4, 4]),
        task="fetch_mocap",
        observations=["object_x", "object_y"],
        actuators=[list(FINGERS)],
        mocap=[MOCAP_ENTRY],
        control_period=0.04,
    )
    with pytest.raises(TaskError) as err:
        load_policy_file(path, task).policy(model, {})
    assert isinstance(err.value, PolicyFileError)
    assert str(err.value).startswith(f"{path.with_suffix('.yaml')}: actuators: ")
    assert "different ctrlranges" in str(err.value)


SIGNED = {"actuators": list(FINGERS), "signs": [1, -1]}


def _mirrored_fetch(folder) -> Path:
    """The Fetch with its right finger's servo range mirrored to [-0.2, 0], as robosuite's
    Panda gripper declares its two fingers ([0, 0.04] and [-0.04, 0], one command [a, -a])."""
    import shutil

    shutil.copytree(FETCH.parents[1], folder / "assets")
    scene = folder / "assets" / "fetch" / FETCH.name
    text = scene.read_text()
    right = 'ctrlrange="0 0.2" joint="robot0:r_gripper_finger_joint"'
    assert right in text
    scene.write_text(text.replace(right, right.replace('"0 0.2"', '"-0.2 0"')))
    return scene


def test_one_column_drives_two_fingers_with_opposite_signs(tmp_path):
    import dataclasses

    from fetch_mocap import fetch_task
    from policy_graphs import tanh_mlp, write

    from mjtrial.policy_files.file import load_policy_file, policy_task
    from mjtrial.sim.engine import iter_batches
    from mjtrial.task import BoundTask

    task = fetch_task(model=_mirrored_fetch(tmp_path))
    path = write(
        tmp_path,
        "fetch",
        tanh_mlp([2, 16, 4], seed=3),
        task="fetch_mocap",
        observations=["object_x", "object_y"],
        actuators=[SIGNED],
        mocap=[MOCAP_ENTRY],
        control_period=0.04,
    )
    policy_file = load_policy_file(path, task)
    values = {
        "state_id": np.arange(3),
        "object_dx": np.array([0.0, 0.05, -0.08]),
        "object_dy": np.array([0.03, -0.06, 0.0]),
    }
    run = lambda t: next(iter_batches(BoundTask.of(t), values, {}, thresholds={}, nthread=1))  # noqa: E731
    by_file = run(policy_task(task, policy_file)).episodes

    # by hand, without signs: the column onto [0, 0.2] (SessionPolicy), then a second column
    # of its negation for the right finger
    class Mirrored(SessionPolicy):
        def __call__(self, obs: np.ndarray) -> np.ndarray:
            action = super().__call__(obs)
            return np.concatenate([action[:, :1], -action[:, :1], action[:, 1:]], axis=1)

    by_hand_actions = (
        Control(FINGERS[0]),
        Control(FINGERS[1]),
        MocapAction(**{k: tuple(v) if isinstance(v, list) else v for k, v in MOCAP_ENTRY.items()}),
    )
    controller = dataclasses.replace(
        task.controller,
        policy=lambda model, params: Mirrored(policy_file.session),
        actions=by_hand_actions,
    )
    by_hand = run(dataclasses.replace(task, controller=controller)).episodes
    np.testing.assert_array_equal(by_file.physics, by_hand.physics)
    left, right = by_file.ctrl[..., 0], by_file.ctrl[..., 1]
    np.testing.assert_array_equal(right, -left)
    assert left.min() > 0 and left.max() <= 0.2 and np.ptp(left) > 0.001


def test_a_signed_column_must_share_one_range_and_give_a_sign_per_actuator(tmp_path):
    from fetch_mocap import fetch_task
    from policy_graphs import tanh_mlp, write

    from mjtrial.policy_files.file import PolicyFileError, load_policy_file

    task = fetch_task()  # both fingers [0, 0.2]: times (1, -1) they are two ranges
    kwargs = dict(
        task="fetch_mocap",
        observations=["object_x", "object_y"],
        mocap=[MOCAP_ENTRY],
        control_period=0.04,
    )
    path = write(tmp_path, "fetch", tanh_mlp([2, 4, 4]), actuators=[SIGNED], **kwargs)
    with pytest.raises(PolicyFileError, match="different ctrlranges times their signs"):
        load_policy_file(path, task).policy(NOMINAL, {})
    odd = {**SIGNED, "signs": [-1]}
    path = write(tmp_path, "odd", tanh_mlp([2, 4, 4]), actuators=[odd], **kwargs)
    with pytest.raises(PolicyFileError) as err:
        load_policy_file(path, task)
    assert str(err.value) == (
        f"{path.with_suffix('.yaml')}: actuators.0.signs: [-1]; expected one sign (1 or -1) "
        "for each of its 2 actuators"
    )
    with pytest.raises(TaskError, match=r"actions\[0\]: signs: expected \+1 or -1 for each"):
        bind_actions(NOMINAL, (Control(FINGERS, signs=(1, 2)),))


class RawSessionPolicy(SessionPolicy):
    """The graph run by hand, every column as given (a relative column is a step, not a ctrl)."""

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        [action] = self.session.run(["action"], {"observations": obs.astype(np.float32)})
        return action.astype(np.float64)


def test_a_contract_column_relative_to_its_joints_runs_as_the_task_s_relative_control(tmp_path):
    """Issue 42 item 15: a contract marks the fingers' column relative to their joints (as
    gymnasium-robotics' Fetch drives them, `Control(FINGERS, relative=True)`), so a policy
    trained on the suite's action runs as trained: the same episodes as the task's own relative
    control with the graph run by hand, the column given raw (no ctrlrange mapping, no clip)."""
    import dataclasses

    task, controller, run, by_file, by_hand = fetch_by_file_and_by_hand(
        tmp_path,
        seed=5,
        fingers_entry={"actuators": list(FINGERS), "relative": True, "scale": 0.5},
        fingers=Control(FINGERS, relative=True, scale=0.5),
        policy_class=RawSessionPolicy,
    )
    np.testing.assert_array_equal(by_file.physics, by_hand.physics)
    np.testing.assert_array_equal(by_file.ctrl, by_hand.ctrl)
    # relative: not the absolute column's ctrl (the fingers' range [0, 0.2] mapped and clipped)
    absolute = dataclasses.replace(controller, actions=(Control(FINGERS), controller.actions[1]))
    assert not np.array_equal(
        run(dataclasses.replace(task, controller=absolute)).episodes.ctrl, by_file.ctrl
    )


@pytest.mark.parametrize(
    ("change", "key"),
    [
        ({"mocap": [{**MOCAP_ENTRY, "scale": float("nan")}]}, "mocap.0.scale: nan"),
        ({"mocap": [{**MOCAP_ENTRY, "max_step": float("inf")}]}, "mocap.0.max_step: inf"),
        (
            {"actuators": [{"actuators": list(FINGERS), "relative": True, "scale": float("nan")}]},
            "actuators.0.scale: nan",
        ),
    ],
)
def test_a_non_finite_number_in_a_contract_s_actions_is_one_line(tmp_path, change, key):
    """Issue 42 item 15: `scale: .nan` passed the schema (a NaN passes every bound) and
    `policy check` after thousands of MuJoCo warnings; now one line naming the key."""
    from fetch_mocap import fetch_task
    from policy_graphs import tanh_mlp, write

    from mjtrial.policy_files.file import PolicyFileError, load_policy_file

    contract = {
        "task": "fetch_mocap",
        "observations": ["object_x", "object_y"],
        "actuators": [list(FINGERS)],
        "mocap": [MOCAP_ENTRY],
        "control_period": 0.04,
    }
    path = write(tmp_path, "fetch", tanh_mlp([2, 4, 4]), **(contract | change))
    with pytest.raises(PolicyFileError) as err:
        load_policy_file(path, fetch_task())
    assert str(err.value) == f"{path.with_suffix('.yaml')}: {key}; expected finite numbers"


def test_a_non_finite_mocap_scale_in_a_task_is_one_line():
    with pytest.raises(TaskError, match=r"^actions\[0\]: scale: expected finite numbers, got nan$"):
        bind_actions(NOMINAL, (MocapAction("robot0:mocap", scale=float("nan")),))
