"""Behaviour cloning of the cart-pole's designed LQR: scikit-learn's `MLPRegressor` fitted on
what the LQR did on the task's development states at the benchmark's 20 ms sensing latency,
exported by skl2onnx and wrapped in the encoder front end (`policies.cartpole`), one file per
training seed (`seed-<k>.onnx`, the regressor's `random_state`) with the folder's contract.

    python -m policies.cartpole_bc.train             # from the repository's root: seeds 1-5

The data: the designed LQR (the task's own policy) on every development state in mjtrial's
engine, each control instant's encoder observations and the control it chose; the features
are the front end's (the observations and their finite differences, scaled), the target the
control as the contract's action, divided by the motor's 15 N range. Instants after the pole
fell (past `fall_angle`) are left out: the LQR there only saturates, and a regressor that
spends its capacity on a spinning pole clones the balancing worse.

skl2onnx's graph reads `features` (a batch dimension without a name) and writes `action`;
`onnx.compose.merge_models` feeds it from the front end's `features`, so the file's inputs are
the front end's (`observations`, `memory_in`, float32, batch dimension "batch"), and the
output's batch dimension is named "batch" too. skl2onnx names its graph with a random uuid:
the graph gets a fixed name, so the same seed writes the same bytes (on the same platform).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from policies import cartpole

FOLDER = Path(__file__).resolve().parent
HIDDEN = (16,)  # one tanh layer: 4-16-1
MAX_ITER = 60  # Adam epochs over the data
SEEDS = (1, 2, 3, 4, 5)


def demonstrations() -> tuple[np.ndarray, np.ndarray, dict]:
    """(features (m, 4), actions (m,)) of the LQR on the development states, and a summary."""
    bound = cartpole.bound_task()
    condition = cartpole.benchmark_condition()
    params = bound.task.parameters(condition)
    n_controls = bound.task.controller.timing(bound.model, params).n_controls
    lqr = bound.task.controller.policy(bound.model, params)
    recorder = cartpole.Recorder(lqr)
    values = cartpole.development_states()
    success, _ = cartpole.run(cartpole.with_policy(bound, lambda m: recorder), values)
    fall = cartpole.thresholds(bound)["fall_angle"]
    ctrl_range = bound.model.actuator_ctrlrange[bound.model.actuator(cartpole.ACTUATORS[0]).id]
    features, actions = [], []
    for calls in recorder.episodes(n_controls):
        front = cartpole.EncoderFeatures(params["control_period"])
        front.reset(len(calls[0][0]))
        fallen = np.zeros(len(calls[0][0]), dtype=bool)
        for observations, ctrl in calls:
            fallen |= np.abs(observations[:, 1]) >= fall
            keep = ~fallen
            features.append(front(observations)[keep])
            actions.append(ctrl[keep, 0] / ctrl_range[1])
    summary = {
        "lqr_development_success_rate": float(success.mean()),
        "samples": int(sum(len(a) for a in actions)),
    }
    return np.concatenate(features), np.concatenate(actions), summary


def fit(features: np.ndarray, actions: np.ndarray, seed: int):
    from sklearn.neural_network import MLPRegressor
    from threadpoolctl import threadpool_limits

    regressor = MLPRegressor(
        hidden_layer_sizes=HIDDEN,
        activation="tanh",
        max_iter=MAX_ITER,
        batch_size=256,
        tol=0.0,
        n_iter_no_change=MAX_ITER,
        random_state=seed,
    )
    with threadpool_limits(1):  # one BLAS thread: the same sums on any machine's core count
        import warnings

        with warnings.catch_warnings():  # max_iter reached is the plan, not a failure
            warnings.simplefilter("ignore")
            regressor.fit(features, actions)
    return regressor


def export(regressor, path: Path, *, period: float, seed: int) -> None:
    """The regressor by skl2onnx, fed by the encoder front end (see the module's docstring)."""
    import onnx
    import skl2onnx
    from onnx import helper
    from skl2onnx.common.data_types import FloatTensorType

    mlp = skl2onnx.convert_sklearn(
        regressor,
        name=f"cartpole_bc_seed_{seed}",
        initial_types=[("features", FloatTensorType([None, 4]))],
        final_types=[(cartpole.OUTPUT, FloatTensorType([None, len(cartpole.ACTUATORS)]))],
        target_opset=cartpole.OPSET,
    )
    nodes, initializers, inputs = cartpole.front_end(period, "features")
    outputs = [
        cartpole.tensor("features", 4),
        cartpole.tensor(cartpole.MEMORY_OUT, cartpole.MEMORY_SIZE),
    ]
    front = helper.make_model(
        helper.make_graph(nodes, "encoder_front_end", inputs, outputs, initializers),
        opset_imports=list(mlp.opset_import),
        ir_version=mlp.ir_version,
    )
    model = onnx.compose.merge_models(
        front,
        mlp,
        io_map=[("features", "features")],
        name=f"cartpole_bc_seed_{seed}",
        producer_name="policies/cartpole_bc/train.py",
        producer_version=f"skl2onnx {skl2onnx.__version__}",
    )
    # the action first, as in every shipped file; skl2onnx leaves its batch dimension unnamed
    outputs = {o.name: onnx.ValueInfoProto() for o in model.graph.output}
    for o in model.graph.output:
        outputs[o.name].CopyFrom(o)
    outputs = [outputs[cartpole.OUTPUT], outputs[cartpole.MEMORY_OUT]]
    del model.graph.output[:]
    model.graph.output.extend(outputs)
    for output in model.graph.output:
        output.type.tensor_type.shape.dim[0].dim_param = "batch"
    # merge_models lists the opset of each part: one entry per domain, as the checker expects
    opsets = {(o.domain, o.version): o for o in model.opset_import}
    del model.opset_import[:]
    model.opset_import.extend(opsets.values())
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, str(path))


class Forward:
    """The regressor's float64 forward pass behind the numpy front end, row by row (its
    `predict`'s matrix products depend on the batch, which the engine refuses)."""

    def __init__(self, regressor, model, period: float) -> None:
        self.layers = list(zip(regressor.coefs_, regressor.intercepts_, strict=True))
        self.front = cartpole.EncoderFeatures(period)
        self.ctrl_range = model.actuator_ctrlrange

    def reset(self, n_episodes: int) -> None:
        self.front.reset(n_episodes)

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        h = self.front(observations)
        for w, b in self.layers[:-1]:
            h = np.tanh(cartpole.dense(h, w, b))
        action = cartpole.dense(h, *self.layers[-1])  # identity output, as MLPRegressor's
        return cartpole.action_to_ctrl(action, self.ctrl_range)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    parser.add_argument("--out", type=Path, default=FOLDER, help="folder of the files")
    parser.add_argument("--no-check", action="store_true", help="skip the onnxruntime check")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    features, actions, summary = demonstrations()
    period = cartpole.control_period()
    print(f"demonstrations: {summary} ({time.perf_counter() - start:.1f} s)", flush=True)
    records = []
    for seed in args.seeds:
        start = time.perf_counter()
        regressor = fit(features, actions, seed)
        export(regressor, args.out / f"seed-{seed}.onnx", period=period, seed=seed)
        record = {
            "seed": seed,
            "network": f"4-{HIDDEN[0]}-1 tanh",
            "epochs": int(regressor.n_iter_),
            "final_loss": round(float(regressor.loss_), 8),
        }
        if not args.no_check:
            record.update(
                cartpole.check_export(
                    args.out / f"seed-{seed}.onnx", lambda m, r=regressor: Forward(r, m, period)
                )
            )
        records.append(record)
        print(f"seed {seed}: {record} ({time.perf_counter() - start:.1f} s)", flush=True)
    cartpole.write_contract(
        args.out,
        period=period,
        producer=(
            "policies/cartpole_bc/train.py: behaviour cloning of the designed LQR (its "
            f"controls on {cartpole.trained_on()}) by scikit-learn's MLPRegressor, "
            f"4-{HIDDEN[0]}-1 tanh on encoder finite differences, one file per random_state; "
            "exported by skl2onnx and wrapped with onnx.compose "
            f"({cartpole.versions('scikit-learn', 'skl2onnx', 'onnx', 'mujoco')})"
        ),
    )
    if not args.no_check:
        (args.out / "training.json").write_text(
            json.dumps({**summary, "seeds": records}, indent=1) + "\n"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
