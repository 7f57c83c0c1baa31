"""Train the cart-pole's MLP policies by CMA-ES over the network's weights, on the task's
development states at the benchmark's 20 ms sensing latency, and export each training seed's
network to ONNX (`seed-<k>.onnx`) with the folder's contract (`policy.yaml`).

    python -m policies.cartpole_mlp.train            # from the repository's root: seeds 1-5

The search is the benchmark's tuning (`mjtrial.benchmark.tuning`) with a network's weights as
the parameters: pycma with its sampling drawn from a seeded generator, each generation's
candidates on the same development states drawn by another, and at the end CMA-ES's mean and
the best distinct candidates judged on every development state, the best rate chosen. A
success rate on 16 states is flat for a network that balances nothing yet, so a candidate's
score adds half the mean fraction of its episodes before the pole fell or the cart left the
track. Episodes run in mjtrial's engine; the network's forward pass is float64 numpy, row by
row, and the exported graph computes it in float32 (each file is then run through
onnxruntime on every development state and compared: `training.json`).

Deterministic: the same seed and budget write the same bytes (on the same platform).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from policies import cartpole

FOLDER = Path(__file__).resolve().parent
HIDDEN = 8  # one tanh layer: 4-8-1, 49 weights
BUDGET = 12_000  # episodes on development states per training seed, finalists included
EPISODES_PER_CANDIDATE = 16
SIGMA0 = 0.5  # the initial step size, in weight units (features and actions are O(1))
FINAL_CANDIDATES = 3
ALIVE_WEIGHT = 0.5  # a candidate's score: success rate + this x mean fraction alive
SEEDS = (1, 2, 3, 4, 5)  # the benchmark's training seeds


def sizes(hidden: int) -> list[tuple[int, int]]:
    return [(4, hidden), (1, hidden), (hidden, 1), (1, 1)]


def unpack(x: np.ndarray, hidden: int) -> list[np.ndarray]:
    """A CMA-ES point as the network's float32 weights [W1, b1, W2, b2] (what is exported)."""
    out, start = [], 0
    for shape in sizes(hidden):
        size = math.prod(shape)
        out.append(np.asarray(x[start : start + size], dtype=np.float32).reshape(shape))
        start += size
    return out


class MlpPolicy:
    """The network as the engine's policy: features from the encoder front end, then
    tanh(tanh(f W1 + b1) W2 + b2) in float64, each row from that row alone."""

    def __init__(self, weights: list[np.ndarray], *, period: float, ctrl_range) -> None:
        self.weights = [w.astype(np.float64) for w in weights]
        self.features = cartpole.EncoderFeatures(period)
        self.ctrl_range = ctrl_range

    def reset(self, n_episodes: int) -> None:
        self.features.reset(n_episodes)

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        h = self.features(observations)
        for w, b in zip(self.weights[::2], self.weights[1::2], strict=True):
            h = np.tanh(cartpole.dense(h, w, b))
        return cartpole.action_to_ctrl(h, self.ctrl_range)


def score(bound, values, weights, rows, period) -> tuple[float, float]:
    """(success rate, graded score) of a network on the development states `rows`."""
    policy = cartpole.with_policy(
        bound, lambda m: MlpPolicy(weights, period=period, ctrl_range=m.actuator_ctrlrange)
    )
    # a search's scores: the chosen network's file is checked where it is evaluated
    success, alive = cartpole.run(policy, values, rows, replay_check=False)
    return float(success.mean()), float(success.mean() + ALIVE_WEIGHT * alive.mean())


def train(seed: int, *, budget: int, hidden: int = HIDDEN) -> tuple[list[np.ndarray], dict]:
    """CMA-ES over the weights for one training seed; the chosen weights and the record."""
    import cma  # pycma imports scipy.stats and matplotlib: only when training

    bound = cartpole.bound_task()
    values = cartpole.development_states()
    period = cartpole.control_period()
    n_dev = len(next(iter(values.values())))
    dim = sum(math.prod(s) for s in sizes(hidden))
    search_rng, states_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2)
    )
    options = {
        "tolflatfitness": np.inf,
        "tolfun": 0,
        "tolfunhist": 0,
        "randn": lambda *shape: search_rng.standard_normal(shape),
        "seed": np.nan,
        "verbose": -9,
        "verb_log": 0,
        "verb_disp": 0,
    }
    es = cma.CMAEvolutionStrategy(np.zeros(dim), SIGMA0, options)
    reserve = FINAL_CANDIDATES * n_dev
    cost = es.popsize * EPISODES_PER_CANDIDATE
    if budget < reserve + cost:
        raise SystemExit(f"--budget: expected at least {reserve + cost} episodes, got {budget}")
    used, history, best = 0, [], []  # best: (-score, -generation, index, x)
    while used + cost <= budget - reserve and not es.stop():
        xs = es.ask()
        rows = np.sort(states_rng.choice(n_dev, EPISODES_PER_CANDIDATE, replace=False))
        graded = [score(bound, values, unpack(x, hidden), rows, period)[1] for x in xs]
        used += cost
        es.tell(xs, [-s for s in graded])
        g = len(history)
        history.append([round(s, 6) for s in graded])
        best.extend((-s, -g, i, x) for i, (x, s) in enumerate(zip(xs, graded, strict=True)))
    best.sort(key=lambda r: r[:3])
    finalists = [("mean", es.result.xfavorite)]
    finalists += [
        (f"generation {-g} candidate {i}", x) for _, g, i, x in best[: FINAL_CANDIDATES - 1]
    ]
    judged = []
    for origin, x in finalists:
        rate, graded = score(bound, values, unpack(x, hidden), np.arange(n_dev), period)
        used += n_dev
        judged.append({"origin": origin, "success_rate": rate, "score": round(graded, 6)})
    chosen = max(range(len(judged)), key=lambda i: judged[i]["success_rate"])
    record = {
        "seed": seed,
        "network": f"4-{hidden}-1 tanh",
        "weights": dim,
        "budget_episodes": budget,
        "episodes_used": used,
        "episodes_per_candidate": EPISODES_PER_CANDIDATE,
        "popsize": int(es.popsize),
        "generations": len(history),
        "sigma0": SIGMA0,
        "final_sigma": round(float(es.sigma), 6),
        "finalists": judged,
        "chosen": judged[chosen]["origin"],
        "development_success_rate": judged[chosen]["success_rate"],
        "generation_best_scores": [max(h) for h in history],
    }
    return unpack(finalists[chosen][1], hidden), record


def export(weights: list[np.ndarray], path: Path, *, period: float, seed: int) -> None:
    """The network as an ONNX graph with the encoder front end (see `policies.cartpole`)."""
    import onnx
    from onnx import helper, numpy_helper

    nodes, initializers, inputs = cartpole.front_end(period, "features")
    outputs = [
        cartpole.tensor(cartpole.OUTPUT, len(cartpole.ACTUATORS)),
        cartpole.tensor(cartpole.MEMORY_OUT, cartpole.MEMORY_SIZE),
    ]
    names = ["w1", "b1", "w2", "b2"]
    initializers += [numpy_helper.from_array(w, n) for w, n in zip(weights, names, strict=True)]
    n = helper.make_node
    nodes += [
        n("MatMul", ["features", "w1"], ["hidden_linear"]),
        n("Add", ["hidden_linear", "b1"], ["hidden_sum"]),
        n("Tanh", ["hidden_sum"], ["hidden"]),
        n("MatMul", ["hidden", "w2"], ["output_linear"]),
        n("Add", ["output_linear", "b2"], ["output_sum"]),
        n("Tanh", ["output_sum"], [cartpole.OUTPUT]),
    ]
    graph = helper.make_graph(nodes, f"cartpole_mlp_seed_{seed}", inputs, outputs, initializers)
    model = helper.make_model(
        graph,
        producer_name="policies/cartpole_mlp/train.py",
        opset_imports=[helper.make_opsetid("", cartpole.OPSET)],
        ir_version=cartpole.IR_VERSION,
    )
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, str(path))


def train_and_export(seed: int, budget: int, out: Path, checked: bool = True) -> dict:
    start = time.perf_counter()
    weights, record = train(seed, budget=budget)
    period = cartpole.control_period()
    export(weights, out / f"seed-{seed}.onnx", period=period, seed=seed)
    if not checked:
        print(f"seed {seed}: {time.perf_counter() - start:.1f} s", flush=True)
        return record
    record.update(
        cartpole.check_export(
            out / f"seed-{seed}.onnx",
            lambda m: MlpPolicy(weights, period=period, ctrl_range=m.actuator_ctrlrange),
        )
    )
    print(
        f"seed {seed}: development success {record['onnxruntime_success_rate']:.3f} "
        f"(onnxruntime), {record['float64_success_rate']:.3f} (float64 forward), "
        f"{record['outcomes_differing']} outcomes differ, controls within "
        f"{record['largest_ctrl_difference']:.2g} N; {time.perf_counter() - start:.1f} s",
        flush=True,
    )
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    parser.add_argument("--budget", type=int, default=BUDGET, help="episodes per seed")
    parser.add_argument("--out", type=Path, default=FOLDER, help="folder of the files")
    parser.add_argument("--jobs", type=int, default=1, help="seeds trained at once")
    parser.add_argument("--no-check", action="store_true", help="skip the onnxruntime check")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    n = len(args.seeds)
    work = (args.seeds, [args.budget] * n, [args.out] * n, [not args.no_check] * n)
    if args.jobs == 1:
        records = list(map(train_and_export, *work))
    else:
        with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
            records = list(pool.map(train_and_export, *work))
    period = cartpole.control_period()
    cartpole.write_contract(
        args.out,
        period=period,
        producer=(
            f"policies/cartpole_mlp/train.py: a 4-{HIDDEN}-1 tanh MLP on encoder finite "
            f"differences, CMA-ES (pycma) over its weights on {cartpole.trained_on()}, one "
            "file per training seed; exported with onnx "
            f"({cartpole.versions('cma', 'onnx', 'mujoco')})"
        ),
    )
    if not args.no_check:
        (args.out / "training.json").write_text(json.dumps(records, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
