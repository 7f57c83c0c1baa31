"""The task interface: loading a task, applying its state parameters, running its episodes
(against a plain mj_step loop), and the preflight's one-line errors for bad task code and
privileged observations."""

from __future__ import annotations

import sys
import threading
from dataclasses import replace

import mujoco
import numpy as np
import pytest
from conftest import REPO_ROOT

from mjtrial.sim import closed_loop
from mjtrial.sim.engine import iter_batches
from mjtrial.sim.physics import FULLPHYSICS
from mjtrial.task import (
    BoundTask,
    Custom,
    JointPosition,
    OpenLoop,
    ProtocolParameter,
    StateParameter,
    Task,
    TaskError,
    load_task,
)
from mjtrial.task.checks import check_observations, run_task_code

CARTPOLE_TASK = "tasks/cartpole_latency/task.py"
THRESHOLDS = {"fall_angle": 0.5}


@pytest.fixture(scope="module")
def cartpole():
    return load_task(CARTPOLE_TASK, repo_root=REPO_ROOT)


def _values(task, n, seed=5):
    rng = np.random.default_rng(seed)
    return {p.name: rng.uniform(p.low, p.high, n) for p in task.state_parameters}


def test_load_by_path_resolves_the_model_beside_the_task(cartpole):
    assert cartpole.model == REPO_ROOT / "tasks" / "cartpole_latency" / "cartpole.xml"
    assert cartpole.state_columns == (
        "state_id",
        "pole_angle",
        "pole_rate",
        "pole_mass",
        "push_force",
        "push_time",
    )


def test_load_by_module_name(tmp_path, monkeypatch):
    package = tmp_path / "mytasks"
    package.mkdir()
    (package / "__init__.py").write_text("")
    source = (REPO_ROOT / CARTPOLE_TASK).read_text()
    (package / "balance.py").write_text(
        source.replace(
            'model="cartpole.xml"', f'model="{REPO_ROOT / "tasks/cartpole_latency/cartpole.xml"}"'
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    task = load_task("mytasks.balance")
    assert task.name == "cartpole_latency" and task.model.is_file()
    sys.modules.pop("mytasks.balance", None)


def test_a_task_package_loads_in_many_threads_at_once():
    """Snakemake runs local jobs in threads of one process (gather, summary): each loads the
    task; before the import lock, one thread's fresh import pulled the other's modules out of
    `sys.modules` mid-import (CI: "'NoneType' object has no attribute '__dict__'")."""
    failures = []

    def load_some():
        for _ in range(15):
            try:
                task = load_task("tasks/gantry_lift/task.py", repo_root=REPO_ROOT)
                assert task.name == "gantry_lift"
            except TaskError as err:
                failures.append(str(err))

    threads = [threading.Thread(target=load_some) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert failures == []


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (None, "tasks/none.py: task file not found"),
        ("x = 1\n", "expected a module-level TASK = mjtrial.task.Task(...)"),
        ("raise RuntimeError('boom')\n", "the task file raised RuntimeError: boom"),
    ],
)
def test_load_errors_are_one_line(tmp_path, text, message):
    if text is None:
        reference = "tasks/none.py"
    else:
        (tmp_path / "task.py").write_text(text)
        reference = str(tmp_path / "task.py")
    with pytest.raises(
        TaskError, match=message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")
    ) as err:
        load_task(reference, repo_root=tmp_path)
    assert "\n" not in str(err.value)


def test_episode_applies_each_parameter_as_declared(cartpole):
    bound = BoundTask.of(cartpole)
    values = {
        "pole_angle": 0.07,
        "pole_rate": -0.3,
        "pole_mass": 0.22,
        "push_force": 1.0,
        "push_time": 0.6,
    }
    model, state = bound.episode(values, scratch=mujoco.MjData(bound.model))
    # the reference, written out by hand
    m = mujoco.MjModel.from_xml_path(str(cartpole.model))
    d = mujoco.MjData(m)
    m.body_mass[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "pole")] = 0.22
    mujoco.mj_setConst(m, d)
    mujoco.mj_resetData(m, d)
    d.qpos[1] = 0.07
    d.qvel[1] = -0.3
    expected = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
    mujoco.mj_getState(m, d, expected, FULLPHYSICS)
    np.testing.assert_array_equal(state, expected)
    np.testing.assert_array_equal(model.body_mass, m.body_mass)
    np.testing.assert_array_equal(model.body_inertia, m.body_inertia)
    assert bound.model.body_mass[2] == 0.1  # the nominal model is untouched


def test_engine_equals_plain_loop_and_batches_do_not_matter(cartpole):
    bound = BoundTask.of(cartpole)
    values = _values(cartpole, 7)
    condition = {"latency": 0.02, "duration": 2.0}
    one = list(iter_batches(bound, values, condition, thresholds=THRESHOLDS, batch_size=7))
    many = list(
        iter_batches(bound, values, condition, thresholds=THRESHOLDS, batch_size=3, nthread=2)
    )
    physics = one[0].episodes.physics
    np.testing.assert_array_equal(np.concatenate([b.episodes.physics for b in many]), physics)
    for key in one[0].outcome:
        np.testing.assert_array_equal(
            np.concatenate([b.outcome[key] for b in many]), one[0].outcome[key]
        )
    controller = cartpole.controller
    params = cartpole.parameters(condition)
    pushes = controller.pushes(bound.model, values)
    scratch = mujoco.MjData(bound.model)
    for i in range(7):
        model, initial = bound.episode({k: v[i] for k, v in values.items()}, scratch=scratch)
        ref = closed_loop.reference_episode(
            model,
            initial,
            controller.policy(bound.model, params),
            bound.observer(controller.observations),
            controller.timing(bound.model, params),
            pushes=pushes.rows([i]),
        )
        np.testing.assert_array_equal(physics[i], ref.physics[0])
        # success, judged naively step by step over the last second (500 steps of 2 ms)
        x, angle = ref.physics[0, -500:, 1], ref.physics[0, -500:, 2]
        naive = all(abs(a) < 0.25 and abs(c) < 1.0 for a, c in zip(angle, x, strict=True))
        assert one[0].outcome["success"][i] == naive


def test_both_conditions_are_informative_on_development_states(cartpole):
    """Neither condition at 0 % or 100 % on 60 development states (seed 7)."""
    bound = BoundTask.of(cartpole)
    rates = []
    for latency in (0.0, 0.02):
        batch = next(
            iter_batches(
                bound,
                _values(cartpole, 60, seed=7),
                {"latency": latency},
                thresholds=THRESHOLDS,
                batch_size=60,
                nthread=2,
            )
        )
        rates.append(batch.outcome["success"].mean())
        assert set(batch.outcome["failure_category"][~batch.outcome["success"]]) <= {
            "fell",
            "left the track",
            "not settled",
        }
    assert all(0.05 < r < 0.95 for r in rates), rates


def _open_loop_pendulum(tmp_path) -> Task:
    (tmp_path / "pendulum.xml").write_text(
        """<mujoco><option timestep="0.01"/><worldbody><body><joint name="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.02" mass="1"/></body></worldbody>
        <actuator><motor name="torque" joint="hinge"/></actuator></mujoco>"""
    )
    return Task(
        name="pendulum",
        title="a pendulum",
        model=tmp_path / "pendulum.xml",
        state_parameters=(StateParameter("angle", "rad", -0.5, 0.5, JointPosition("hinge")),),
        protocol_parameters=(ProtocolParameter("torque", "N m", 0.5),),
        controller=OpenLoop(lambda model, p: np.full((200, 1), p["torque"])),
        success=lambda e: e.physics[:, -1, 1] > 0,
        measure=lambda e: {},
    )


def test_open_loop_task_equals_plain_mj_step(tmp_path):
    task = _open_loop_pendulum(tmp_path)
    bound = BoundTask.of(task)
    values = {"angle": np.array([-0.4, 0.1, 0.3])}
    batch = next(iter_batches(bound, values, {"torque": 0.2}, thresholds={}))
    for i, angle in enumerate(values["angle"]):
        m = mujoco.MjModel.from_xml_path(str(task.model))
        d = mujoco.MjData(m)
        d.qpos[0] = angle
        d.ctrl[0] = 0.2
        for _ in range(200):
            mujoco.mj_step(m, d)
        assert batch.episodes.physics[i, -1, 1] == d.qpos[0]
        assert batch.outcome["success"][i] == (d.qpos[0] > 0)


def test_privileged_observation_is_refused_unless_allowed(cartpole):
    cheating = replace(
        cartpole,
        controller=replace(
            cartpole.controller, observations=("cart_position", "pole_angle", "pole_rate")
        ),
    )
    with pytest.raises(TaskError, match="the policy reads 'pole_rate', a privileged observation"):
        check_observations(cheating, {})
    assert check_observations(cheating, {"pole_rate": "a gyro is planned"}) == {
        "pole_rate": "a gyro is planned"
    }
    assert check_observations(cartpole, {}) == {}


def _bad(cartpole, **changes):
    return BoundTask.of(replace(cartpole, **changes))


class _NanPolicy:
    def reset(self, n):
        pass

    def __call__(self, obs):
        return np.full((len(obs), 1), np.nan)


BAD_TASKS = [
    ("success raises", lambda t: {"success": lambda e: 1 / 0}, "success raised ZeroDivisionError"),
    (
        "success wrong shape",
        lambda t: {"success": lambda e: np.ones((len(e.physics), 2), bool)},
        r"success: expected an array of shape \(1,\)",
    ),
    (
        "measure missing",
        lambda t: {"measure": lambda e: {}},
        "measure: expected a value for 'peak_angle'",
    ),
    (
        "non-finite controls",
        lambda t: {"controller": replace(t.controller, policy=lambda m, p: _NanPolicy())},
        "non-finite controls",
    ),
    (
        "undeclared observation",
        lambda t: {"controller": replace(t.controller, observations=("pole_tip",))},
        "reads observation 'pole_tip', which is not declared",
    ),
    (
        "parameter never applied",
        lambda t: {
            "state_parameters": (
                *t.state_parameters,
                StateParameter("friction", "1", 0.1, 1.0, Custom(lambda m, d, v: None)),
            )
        },
        "state parameter 'friction': the episode is the same at its low and high values",
    ),
]


@pytest.mark.parametrize(("case", "change", "message"), BAD_TASKS, ids=[c[0] for c in BAD_TASKS])
def test_bad_task_code_is_one_line_naming_the_task_file(cartpole, case, change, message):
    bound = _bad(cartpole, **change(cartpole))
    with pytest.raises(TaskError, match=message) as err:
        run_task_code(bound, {"fast": {"latency": 0.0, "duration": 1.5}}, thresholds=THRESHOLDS)
    assert str(err.value).startswith(str(cartpole.source))
    assert "\n" not in str(err.value)


def test_missing_model_element_names_the_parameter(cartpole):
    task = replace(
        cartpole,
        state_parameters=(StateParameter("tilt", "rad", 0, 1, JointPosition("no_such_joint")),),
    )
    with pytest.raises(
        TaskError, match="state parameter 'tilt': expected a joint named 'no_such_joint'"
    ):
        BoundTask.of(task)


def test_the_cartpole_task_passes_its_preflight(cartpole):
    run_task_code(
        BoundTask.of(cartpole),
        {"zero": {"latency": 0.0}, "twenty": {"latency": 0.02}},
        thresholds=THRESHOLDS,
    )


class _LargeBatchesDiffer:
    """Issue 26 case 1's policy: the cart-pole's own, but 1 % more force in a batch of more
    than 8 rows. The preflight (one row against a batch of 4) cannot see it."""

    def __init__(self, policy):
        self.policy = policy

    def reset(self, n_episodes):
        self.policy.reset(n_episodes)

    def __call__(self, observations):
        controls = self.policy(observations)
        return controls * 1.01 if len(observations) > 8 else controls


def test_a_policy_that_depends_on_its_batch_fails_the_rollout_in_one_line(cartpole):
    own = cartpole.controller.policy
    bound = _bad(
        cartpole,
        controller=replace(cartpole.controller, policy=lambda m, p: _LargeBatchesDiffer(own(m, p))),
    )
    condition = {"latency": 0.02, "duration": 1.5}
    run_task_code(bound, {"twenty": condition}, thresholds=THRESHOLDS)  # the preflight passes
    values = _values(cartpole, 10)
    small = list(iter_batches(bound, values, condition, thresholds=THRESHOLDS, batch_size=5))
    assert len(small) == 2  # batches of 5 (a shard_size of 5): what they give is what alone gives
    with pytest.raises(TaskError) as err:  # one batch of 10 (a shard_size of 10)
        list(iter_batches(bound, values, condition, thresholds=THRESHOLDS, batch_size=10))
    message = str(err.value)
    assert message.startswith(f"{cartpole.source}: policy: batch dependence: episode row ")
    assert " of a batch of 10 " in message
    assert "(rollout.shard_size)" in message and "\n" not in message


def test_the_old_state_qpos_import_still_works_with_a_deprecation_warning():
    import mjtrial.sim.physics
    import mjtrial.task

    with pytest.warns(DeprecationWarning, match=r"mjtrial\.sim\.physics\.STATE_QPOS"):
        from mjtrial.task import STATE_QPOS
    assert STATE_QPOS == mjtrial.sim.physics.STATE_QPOS
    with pytest.raises(AttributeError, match="NO_SUCH_NAME"):
        mjtrial.task.NO_SUCH_NAME  # noqa: B018


def test_a_task_file_imports_a_module_beside_it_as_the_guide_says(tmp_path):
    """docs/guide/task.md: an `__init__.py` in the task's folder, then `from .module import`;
    the module is an input of the task like the task file."""
    from mjtrial.task import load_task, task_files

    folder = tmp_path / "tasks" / "my_task"
    folder.mkdir(parents=True)
    (folder / "__init__.py").write_text("")
    (folder / "protocol.py").write_text('TASK_NAME = "my_balance"\n')
    source = (REPO_ROOT / "tasks/cartpole_latency/task.py").read_text()
    model = REPO_ROOT / "tasks/cartpole_latency/cartpole.xml"
    source = source.replace('model="cartpole.xml"', f'model="{model}"')
    source = source.replace('name="cartpole_latency"', "name=TASK_NAME")
    source = source.replace(
        "from __future__ import annotations\n",
        "from __future__ import annotations\n\nfrom .protocol import TASK_NAME\n",
    )
    (folder / "task.py").write_text(source)
    task = load_task("tasks/my_task/task.py", repo_root=tmp_path)
    assert task.name == "my_balance"
    assert folder / "protocol.py" in task_files(folder / "task.py")
