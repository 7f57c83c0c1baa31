"""A task's `episode_setup` (a suite's own reset) on gymnasium-robotics' Fetch model: the
initial state and the mocap pose it leaves equal a plain loop doing the same by hand, the
mocap pose survives into `mujoco.rollout`, model copies are never reused across episodes, an
exception names the task file; and a closed-loop Fetch task whose policy moves the mocap
records the mocap target where it was at every logged step."""

from __future__ import annotations

import copy
from pathlib import Path

import mujoco
import numpy as np
import pytest
import rerun as rr
from conftest import REPO_ROOT
from fetch_mocap import FETCH, NOMINAL, fetch_setup, fetch_task
from mujoco import rollout

from mjtrial.recording import write_condition_recordings
from mjtrial.recording.names import body_entity, logged_steps
from mjtrial.sim.engine import iter_batches
from mjtrial.sim.physics import FULLPHYSICS
from mjtrial.stages.rollout import episode_records, recording_spec
from mjtrial.task import BoundTask, TaskError

VALUES = {"object_dx": np.array([0.0, 0.04, -0.07]), "object_dy": np.array([0.02, -0.05, 0.0])}


def _by_hand(dx: float, dy: float) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """What a user writes: a copy of the model, reset, the suite's setup, the object moved."""
    m = copy.copy(NOMINAL)
    d = mujoco.MjData(m)
    mujoco.mj_resetData(m, d)
    fetch_setup(m, d, {})
    adr = m.joint("object0:joint").qposadr[0]
    d.qpos[adr] += dx
    d.qpos[adr + 1] += dy
    return m, d


def test_the_setup_gives_the_state_and_mocap_pose_of_doing_it_by_hand():
    bound = BoundTask.of(fetch_task(), NOMINAL)
    assert not bound.reuses_models  # the setup may change any field: fresh copies
    scratch = mujoco.MjData(NOMINAL)
    for dx, dy in zip(VALUES["object_dx"], VALUES["object_dy"], strict=True):
        model, state = bound.episode({"object_dx": dx, "object_dy": dy}, scratch=scratch)
        m, d = _by_hand(dx, dy)
        expected = np.empty(len(state))
        mujoco.mj_getState(m, d, expected, FULLPHYSICS)
        np.testing.assert_array_equal(state, expected)
        np.testing.assert_array_equal(model.eq_data, m.eq_data)
        assert not np.array_equal(model.eq_data, NOMINAL.eq_data)  # the setup did edit it
        # the mocap pose survives into mujoco.rollout: 40 steps there equal 40 plain steps
        with rollout.Rollout(nthread=0) as runner:
            physics, _ = runner.rollout(
                model, mujoco.MjData(model), state, np.zeros((1, 40, model.nu))
            )
        d.qacc_warmstart[:] = 0.0  # rollout starts from a zero warm start
        rows = []
        for _ in range(40):
            mujoco.mj_step(m, d)
            row = np.empty(len(state))
            mujoco.mj_getState(m, d, row, FULLPHYSICS)
            rows.append(row)
        np.testing.assert_array_equal(physics[0], np.stack(rows))


def test_a_setup_that_accumulates_gets_a_fresh_model_every_episode():
    """A setup that adds to a model field would drift on a reused copy; episodes run alone
    and together agree."""

    def drifting(model, data, values):
        fetch_setup(model, data, values)
        model.body_mass[model.body("object0").id] += 1.0  # wrong on a reused copy

    bound = BoundTask.of(fetch_task(setup=drifting), NOMINAL)
    together = next(iter_batches(bound, VALUES, {}, thresholds={}, nthread=1)).episodes.physics
    for i in range(3):
        alone = {k: v[i : i + 1] for k, v in VALUES.items()}
        batch = next(iter_batches(bound, alone, {}, thresholds={}, nthread=1, batch_size=1))
        np.testing.assert_array_equal(batch.episodes.physics[0], together[i])


def test_an_exception_in_the_setup_is_one_line_naming_the_task_file():
    def broken(model, data, values):
        raise KeyError("robot0:nope")

    task = fetch_task(setup=broken, source=Path("tasks/fetch/task.py"))
    bound = BoundTask.of(task, NOMINAL)
    with pytest.raises(TaskError) as err:
        bound.episode({"object_dx": 0.0, "object_dy": 0.0}, scratch=mujoco.MjData(NOMINAL))
    assert str(err.value) == "tasks/fetch/task.py: episode_setup raised KeyError: 'robot0:nope'"


def test_the_recording_draws_the_mocap_target_at_every_logged_step(tmp_path):
    bound = BoundTask.of(fetch_task(), NOMINAL)
    values = {"state_id": np.arange(3), **VALUES}
    [batch] = iter_batches(bound, values, {}, thresholds={}, nthread=1)
    mocap = batch.episodes.mocap
    assert mocap.shape == (3, 160, 1, 7)
    n_steps = batch.episodes.physics.shape[1]
    spec = recording_spec(bound, n_steps, 50.0)
    write_condition_recordings(
        tmp_path,
        spec=spec,
        condition="c",
        episodes=episode_records(bound.task, batch),
        stamp={"mjtrial_stamp": 1, "rule": "test_episode_setup"},
    )
    entity = "/" + body_entity(NOMINAL, NOMINAL.body("robot0:mocap").id)
    steps = logged_steps(n_steps, spec.log_every)
    for i in range(3):
        [path] = tmp_path.glob(f"c-state-{i:06d}.rrd")
        reader = rr.chunk.RrdReader(str(path))
        [recording] = reader.recordings()
        chunks = [
            c
            for c in reader.store(store=recording).stream().filter(content=entity)
            if c.entity_path == entity
        ]
        assert not any(
            c.is_static and "Transform3D:translation" in c.to_record_batch().schema.names
            for c in chunks
        )  # a static pose would hide the logged ones
        [pose] = [c.to_record_batch() for c in chunks if not c.is_static]
        names = pose.schema.names
        translation = np.array(
            [t[0] for t in pose.column(names.index("Transform3D:translation")).to_pylist()]
        )
        quaternion = np.array(
            [q[0] for q in pose.column(names.index("Transform3D:quaternion")).to_pylist()]
        )
        np.testing.assert_allclose(translation, mocap[i, steps, 0, :3], atol=1e-6)  # float32
        w, x, y, z = (
            mocap[i, steps, 0, 3:] / np.linalg.norm(mocap[i, steps, 0, 3:], axis=1)[:, None]
        ).T
        np.testing.assert_allclose(quaternion, np.stack([x, y, z, w], 1), atol=1e-6)
    # the target moved during the episode, so a static pose would have been wrong
    assert np.ptp(mocap[:, :, 0, 0], axis=1).min() > 0.01


def test_the_preflight_runs_the_setup_and_names_its_exception():
    from mjtrial.task.checks import run_task_code

    allowed = {"object_x": "test", "object_y": "test"}
    run_task_code(
        BoundTask.of(fetch_task(), NOMINAL), {"c": {}}, thresholds={}, allowed_privileged=allowed
    )

    def broken(model, data, values):
        raise ValueError("no weld")

    task = fetch_task(setup=broken, source=Path("tasks/fetch/task.py"))
    with pytest.raises(TaskError) as err:
        run_task_code(
            BoundTask.of(task, NOMINAL), {"c": {}}, thresholds={}, allowed_privileged=allowed
        )
    assert str(err.value) == "tasks/fetch/task.py: episode_setup raised ValueError: no weld"


def test_verify_resimulates_a_mocap_task_alone_as_its_rollout_ran(tmp_path):
    """The rollout stage's batches and verify's re-simulation (each episode alone, from the
    states file, the task loaded from its file) give the same rows, a measure read from the
    mocap targets included."""
    from mjtrial.sim.resimulation import resimulated_outcome
    from mjtrial.stages.rollout import (
        condition_batches,
        condition_task,
        read_state_values,
        rollout_columns,
    )
    from mjtrial.stages.states import build_states

    task_file = tmp_path / "task.py"
    tests = Path(__file__).parent
    task_file.write_text(
        f"import sys\nsys.path.insert(0, {str(tests)!r})\n"
        "from fetch_mocap import fetch_task\nTASK = fetch_task()\n"
    )
    ranges = {"object_dx": [-0.1, 0.1], "object_dy": [-0.1, 0.1]}
    states = {"seed": 3, "development_seed": 4, "n": 6, "ranges": ranges, "task": str(task_file)}
    states_path = tmp_path / "states.parquet"
    build_states(states_slice=states, output=states_path, repo_root=REPO_ROOT)
    condition = {"task": str(task_file), "condition": "c"}
    bound = condition_task(condition, FETCH, repo_root=REPO_ROOT)
    values = read_state_values(states_path, bound.task)
    rows = {c: [] for c in rollout_columns(bound.task)}
    for batch in condition_batches(bound, condition, values, nthread=2, batch_size=4):
        rows["state_id"].append(batch.values["state_id"])
        for c in list(rows)[1:]:
            rows[c].append(batch.outcome[c])
    ran = {c: np.concatenate(v) for c, v in rows.items()}
    ids = [4, 0, 5]
    again = resimulated_outcome(condition, FETCH, states_path, ids, repo_root=REPO_ROOT)
    np.testing.assert_array_equal(again.column("state_id").to_numpy(), ids)
    for c in ("success", "final_target_y", "steps_simulated"):
        np.testing.assert_array_equal(again.column(c).to_numpy(), ran[c][ids])
    assert len(set(ran["final_target_y"])) == 6  # each episode's own


def metaworld_setup(model: mujoco.MjModel, data: mujoco.MjData, values) -> None:
    """Metaworld's `reset_mocap_welds`: every weld to identity, then the mocap on the body
    welded to it."""
    for i in range(model.neq):
        if model.eq_type[i] == mujoco.mjtEq.mjEQ_WELD:
            model.eq_data[i, :7] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    mujoco.mj_forward(model, data)
    for i in range(model.neq):
        mocap = model.body_mocapid[model.eq_obj1id[i]]
        data.mocap_pos[mocap] = data.xpos[model.eq_obj2id[i]]
        data.mocap_quat[mocap] = data.xquat[model.eq_obj2id[i]]


def test_a_weld_reset_setup_equals_the_same_statements_written_by_hand():
    task = fetch_task(setup=metaworld_setup)
    bound = BoundTask.of(task, NOMINAL)
    model, state = bound.episode(
        {"object_dx": 0.03, "object_dy": -0.02}, scratch=mujoco.MjData(NOMINAL)
    )
    # by hand, statement by statement: a copy, reset, the weld, the mocap on the hand, the
    # object moved (JointPosition adds to the reset pose)
    m = copy.copy(NOMINAL)
    d = mujoco.MjData(m)
    m.eq_data[0, :7] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    mujoco.mj_forward(m, d)
    hand = m.body("robot0:gripper_link").id
    d.mocap_pos[0], d.mocap_quat[0] = d.xpos[hand], d.xquat[hand]
    adr = m.joint("object0:joint").qposadr[0]
    d.qpos[adr] += 0.03
    d.qpos[adr + 1] += -0.02
    expected = np.empty(len(state))
    mujoco.mj_getState(m, d, expected, FULLPHYSICS)
    np.testing.assert_array_equal(state, expected)
    np.testing.assert_array_equal(model.eq_data, m.eq_data)
    mocap = m.body("robot0:mocap").id
    np.testing.assert_array_equal(model.body_pos[mocap], d.mocap_pos[0])  # kept for resets
    np.testing.assert_array_equal(model.body_quat[mocap], d.mocap_quat[0])
    assert not np.array_equal(model.body_pos[mocap], NOMINAL.body_pos[mocap])


def _unseeded(model, data, values):
    """The suite's setup with the object nudged by an unseeded generator."""
    fetch_setup(model, data, values)
    data.qpos[model.joint("object0:joint").qposadr[0]] += np.random.default_rng().normal(0, 1e-3)


def _counted(model, data, values, calls=[]):  # noqa: B006 - module state, on purpose
    """The suite's setup with the object moved by the number of earlier calls."""
    fetch_setup(model, data, values)
    calls.append(1)
    data.qpos[model.joint("object0:joint").qposadr[0]] += 1e-3 * len(calls)


@pytest.mark.parametrize("setup", [_unseeded, _counted])
def test_the_preflight_refuses_a_setup_that_is_not_a_function_of_its_arguments(setup):
    """Its episode differs between two setups of one state: the pairs' conditions would run
    different episodes. One line naming the task file and the function (issue 42, item 11)."""
    from mjtrial.task.checks import check_setup_is_a_function, run_task_code

    task = fetch_task(setup=setup, source=Path("tasks/fetch/task.py"))
    expected = (
        "tasks/fetch/task.py: episode_setup: not a function of its arguments: the nominal "
        "state's episode differed between two setups (another state's between them); expected "
        "the same model and initial state for the same values (no unseeded randomness, module "
        "state, call order or clock)"
    )
    with pytest.raises(TaskError) as err:
        check_setup_is_a_function(BoundTask.of(task, NOMINAL))
    assert str(err.value) == expected
    allowed = {"object_x": "test", "object_y": "test"}
    with pytest.raises(TaskError, match="episode_setup: not a function of its arguments"):
        run_task_code(
            BoundTask.of(task, NOMINAL), {"c": {}}, thresholds={}, allowed_privileged=allowed
        )
    check_setup_is_a_function(BoundTask.of(fetch_task(), NOMINAL))  # the suite's own: passes


def test_the_report_gives_the_weld_as_the_setup_leaves_it():
    """Issue 42 item 15: the report's weld line gave only the compiled model's solref; a
    setup that resets the weld (Metaworld's Sawyer) and scales its torque sets what acts. The
    line now gives the relative pose, anchor and torque scale of the nominal episode's model,
    after the setup: the values the setup wrote."""
    from mjtrial.report.model import equality_lines
    from mjtrial.report.setup import _nominal_start

    def sawyer_like(model, data, values):
        metaworld_setup(model, data, values)
        model.eq_data[0, 3:6] = [0.01, 0.0, -0.02]  # relative position
        model.eq_data[0, 10] = 0.5  # torque scale

    task = fetch_task(setup=sawyer_like)
    [head, line] = equality_lines(_nominal_start(NOMINAL, task), after_setup=True)
    assert head == (
        "- Equality constraints (the nominal episode's model, after the task's `episode_setup`):"
    )
    assert line == (
        "  - weld 0 (robot0:mocap to robot0:gripper_link): active, solref 0.02, 1, relative "
        "pose (0.01, 0, -0.02) m and (1, 0, 0, 0) (w, x, y, z), anchor (0, 0, 0) m, torque "
        "scale 0.5"
    )
    # without a setup: the compiled model's, said so (Fetch's weld scales torque by 1)
    [head, line] = equality_lines(_nominal_start(NOMINAL, fetch_task(setup=None)))
    assert head == "- Equality constraints (from the compiled model):"
    assert line.endswith(f"torque scale {NOMINAL.eq_data[0, 10]:g}")
