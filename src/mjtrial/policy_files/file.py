"""Trained policies from files: an ONNX graph with a small YAML contract, run by onnxruntime on
the closed-loop engine's batches.

The contract (`workflow/schemas/policy.schema.yaml`) is `<file>.yaml` beside `<file>.onnx`, else
`policy.yaml` in the same folder. It names the task's observations that feed the graph (so the
privileged-observation check applies to them as to any policy), the actuators its output drives
and how (`ctrlrange`: [-1, 1] onto each actuator's range; `raw`; one column may drive several
actuators), the mocap bodies its further columns move (`mjtrial.task.MocapAction`, 3 columns
each), the control period it was
trained at, an optional normalization and an optional recurrent state. Everything is checked
against the task and the graph before any rollout: each mismatch is one line naming the file.
A graph saved with external data (its initializers' bytes in files beside it) is made of those
files too: each is an input, stamped and copied with the graph (`policy_file_paths`).

Determinism: the project promises that an episode's outcome does not depend on its batch or on
thread counts, and that two runs agree bit for bit; onnxruntime promises neither in general.
A session here runs on one thread, sequentially, on the CPU provider (`SESSION_SETTINGS`, recorded
in the stamps); with these settings the networks tested gave every row the same bits alone as in
any batch (tests/test_policy_file.py), and the engine replays every batch's first instants in
other batches (`closed_loop.check_replayed`), so a network for which that fails stops the run
with one line instead of giving batch-dependent results.

A non-finite action is a failure of the episode, not an error of the run: from the first
control instant whose action has a NaN or an infinity, the episode gets ctrl 0 (control stops)
and its failure category is `NONFINITE_ACTION`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jsonschema
import mujoco
import numpy as np
import yaml

from mjtrial import REPO_ROOT
from mjtrial.files.schemas import packaged_schema
from mjtrial.policy_files.one_row import OneRow
from mjtrial.policy_files.onnx_data import GraphFormatError, external_data
from mjtrial.sim.engine import MAX_BATCH
from mjtrial.sim.physics import ModelError, load_model
from mjtrial.task import ClosedLoop, Control, MocapAction, Task, TaskError, address

if TYPE_CHECKING:
    import onnxruntime

SCHEMA_PATH = REPO_ROOT / "workflow" / "schemas" / "policy.schema.yaml"
FOLDER_CONTRACT = "policy.yaml"  # one contract for every file of a folder
# What a session runs with: one thread and sequential execution, so that no reduction is split
# by a thread count, and the CPU provider only. Measured (onnxruntime 1.31.1, this project's
# 2-core machine, tanh MLPs 2-64-64-1, 12-256-256-6, 40-512-512-512-12): every slice of 1 to 199
# rows gave the rows of one batch of 200 bit for bit, with graph optimizations on and off and on
# 1 and 2 threads; a second thread made no call faster (16 rows: 9-134 µs either way), so one
# costs nothing here. Optimizations stay on (onnxruntime's default): off cost up to 20 % more per
# call. Whole batches, not row by row: 16 rows in one call cost about what 1 row does.
SESSION_SETTINGS: dict[str, Any] = {
    "providers": ["CPUExecutionProvider"],
    "intra_op_num_threads": 1,
    "inter_op_num_threads": 1,
    "execution_mode": "ORT_SEQUENTIAL",
    "graph_optimization_level": "ORT_ENABLE_ALL",
}
_FLOAT32 = "tensor(float)"
# The batch sizes a graph's shapes are probed at: a small one, and the engine's largest batch
# (one call, under a millisecond for the networks tested).
PROBE_ROWS = (2, MAX_BATCH)
_IR_TOO_NEW = re.compile(r"Unsupported model IR version: (\d+), max supported IR version: (\d+)")


class PolicyFileError(TaskError):
    """A policy file or its contract that does not fit the task or the graph (one line)."""


@dataclass(frozen=True)
class Recurrent:
    """State carried between control instants: fed to `input`, read back from `output`."""

    input: str
    output: str
    size: int


@dataclass(frozen=True)
class RelativeColumn:
    """A contract's column relative to its actuators' joints: `Control(relative=True)`."""

    actuators: tuple[str, ...]
    scale: float = 1.0


@dataclass(frozen=True)
class Contract:
    """A policy file's contract, as read (see the module's docstring)."""

    source: Path  # the contract's own file
    task: str
    observations: tuple[str, ...]
    input: str
    output: str
    # per output column: one actuator or several, or a column relative to their joints
    actuators: tuple[str | tuple[str, ...] | RelativeColumn, ...]
    action_scale: str
    control_period: float
    mean: np.ndarray | None = None  # (n_columns,) normalization, or None
    std: np.ndarray | None = None
    recurrent: tuple[Recurrent, ...] = ()
    producer: str = ""
    mocap: tuple[Mapping[str, Any], ...] = ()  # `MocapAction` arguments, 3 columns each
    signs: tuple[tuple[int, ...], ...] = ()  # per actuators entry: its actuators' signs, or ()

    def signs_of(self, k: int) -> tuple[int, ...]:
        """The signs of the k-th actuators entry's actuators; () when it gives none (all +1)."""
        return self.signs[k] if self.signs else ()

    @property
    def n_outputs(self) -> int:
        return len(self.actuators) + 3 * len(self.mocap)

    @property
    def actions(self) -> tuple[Control | MocapAction, ...]:
        """The task's actions the output drives; () when it is the plain one column per
        actuator (the policy then gives every actuator's ctrl, as before actions existed)."""
        if not self.mocap and all(isinstance(a, str) for a in self.actuators):
            return ()
        return (
            *(
                Control(a.actuators, relative=True, scale=a.scale)
                if isinstance(a, RelativeColumn)
                else Control(a, signs=self.signs_of(k) or None)
                for k, a in enumerate(self.actuators)
            ),
            *(
                MocapAction(**{k: tuple(v) if isinstance(v, list) else v for k, v in m.items()})
                for m in self.mocap
            ),
        )


def contract_path(onnx_file: Path) -> Path:
    """The contract of a policy file: `<file>.yaml` beside it, else the folder's `policy.yaml`."""
    own = onnx_file.with_suffix(".yaml")
    return own if own.is_file() else onnx_file.with_name(FOLDER_CONTRACT)


def data_files(onnx_file: Path) -> list[Path]:
    """The external data files the graph loads (`mjtrial.policy_files.onnx_data`), each a file
    inside the graph's folder; `PolicyFileError` (one line naming the graph, the tensor and the
    location) for one that is missing or elsewhere, or not an initializer of the main graph (a node
    attribute's or a subgraph's: onnxruntime 1.31.1 reads those relative to the working folder,
    not the graph's, measured)."""
    try:
        tensors = external_data(onnx_file)
    except GraphFormatError:
        return []  # onnxruntime's load then says why, in one line (`open_session`)
    folder = onnx_file.parent
    files: list[Path] = []
    for tensor in tensors:
        where = f"{onnx_file}: tensor {tensor.name!r} has its data in {tensor.location!r}"
        file = folder / tensor.location
        if not tensor.main:
            raise PolicyFileError(
                f"{where}, a node attribute's or a subgraph's, which onnxruntime looks for in "
                "the working folder; expected external data for the main graph's initializers "
                "only"
            )
        if (
            Path(tensor.location).is_absolute()
            or ".." in Path(tensor.location).parts
            or not file.resolve().is_relative_to(folder.resolve())
        ):
            raise PolicyFileError(
                f"{where}; expected a file in the graph's folder (a relative path without "
                "'..', not a link out of it)"
            )
        if not file.is_file():
            raise PolicyFileError(f"{where}, which is not a file beside it; expected {file}")
        if file not in files:
            files.append(file)
    return files


def policy_file_paths(onnx_file: str | Path) -> list[Path]:
    """Every file a policy file's run reads: the graph, its contract and the graph's external
    data files: the inputs of a job that runs it, stamped and copied with the run. Lenient
    (a graph that cannot be read gives graph and contract): `load_policy_file` is the check."""
    onnx_file = Path(onnx_file)
    try:
        data = data_files(onnx_file) if onnx_file.is_file() else []
    except PolicyFileError:
        tensors = external_data(onnx_file)
        data = list(dict.fromkeys(onnx_file.parent / t.location for t in tensors))
    return [onnx_file, contract_path(onnx_file), *data]


def read_contract(onnx_file: Path) -> Contract:
    """The contract of `onnx_file`, validated against its schema; `PolicyFileError` (one line
    naming the contract file and the key) otherwise."""
    path = contract_path(onnx_file)
    if not path.is_file():
        raise PolicyFileError(
            f"{onnx_file}: no contract; expected {onnx_file.with_suffix('.yaml').name} beside it "
            f"or {FOLDER_CONTRACT} in its folder"
        )
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise PolicyFileError(f"{path}: not valid YAML ({str(err).splitlines()[0]})") from None
    schema = packaged_schema(SCHEMA_PATH)
    error = jsonschema.exceptions.best_match(
        jsonschema.Draft202012Validator(schema).iter_errors(raw)
    )
    if error is not None:
        key = ".".join(str(p) for p in error.absolute_path) or "(top level)"
        raise PolicyFileError(f"{path}: {key}: {error.message}")
    norm = raw.get("normalization")
    # JSON Schema's `number` takes YAML's .nan and .inf, and a NaN passes every bound
    for key, values in [
        ("control_period", [raw["control_period"]]),
        *((f"normalization.{k}", norm[k]) for k in ("mean", "std") if norm),
        *(
            (f"mocap.{i}.{k}", v if isinstance(v, list) else [v])
            for i, m in enumerate(raw.get("mocap") or ())
            for k, v in m.items()
            if k not in ("body", "relative_to")
        ),
        *(
            (f"actuators.{i}.scale", [a["scale"]])
            for i, a in enumerate(raw["actuators"])
            if isinstance(a, dict) and "scale" in a
        ),
    ]:
        bad = [v for v in values if not math.isfinite(v)]
        if bad:
            raise PolicyFileError(f"{path}: {key}: {bad[0]}; expected finite numbers")
    for k, entry in enumerate(raw["actuators"]):
        if isinstance(entry, dict) and "signs" in entry and len(entry["signs"]) != len(
            entry["actuators"]
        ):
            raise PolicyFileError(
                f"{path}: actuators.{k}.signs: {entry['signs']}; expected one sign (1 or -1) "
                f"for each of its {len(entry['actuators'])} actuators"
            )
    return Contract(
        source=path,
        task=raw["task"],
        observations=tuple(raw["observations"]),
        input=raw["input"],
        output=raw["output"],
        actuators=tuple(_column(a) for a in raw["actuators"]),
        action_scale=raw["action_scale"],
        control_period=float(raw["control_period"]),
        mean=None if norm is None else np.asarray(norm["mean"], dtype=np.float64),
        std=None if norm is None else np.asarray(norm["std"], dtype=np.float64),
        recurrent=tuple(Recurrent(**r) for r in raw.get("recurrent") or ()),
        producer=raw.get("producer", ""),
        mocap=tuple(raw.get("mocap") or ()),
        signs=tuple(
            tuple(a["signs"]) if isinstance(a, dict) and "signs" in a else ()
            for a in raw["actuators"]
        ),
    )


def _column(entry: Any) -> str | tuple[str, ...] | RelativeColumn:
    """A contract's `actuators` entry (schema-checked) as `Contract.actuators` holds it: a
    name, a tuple of names (a list, or a signed column's: its signs are `Contract.signs`), or
    a column relative to the joints."""
    if isinstance(entry, dict):
        names = entry["actuators"]
        names = (names,) if isinstance(names, str) else tuple(names)
        if entry.get("relative"):
            return RelativeColumn(names, float(entry.get("scale", 1.0)))
        return names
    return entry if isinstance(entry, str) else tuple(entry)


def runtime_settings() -> dict[str, Any]:
    """onnxruntime's version and the session settings, as the stamps record them."""
    import onnxruntime  # here: only a run with a policy file pays its import (about 19 MB)

    return {"onnxruntime": onnxruntime.__version__, **SESSION_SETTINGS}


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def open_session(onnx_file: Path) -> onnxruntime.InferenceSession:
    """An onnxruntime session with `SESSION_SETTINGS`; `PolicyFileError` if onnxruntime cannot
    read the file (an IR version newer than it reads is said with the version to export)."""
    import onnxruntime  # here: only a run with a policy file pays its import (about 19 MB)

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = SESSION_SETTINGS["intra_op_num_threads"]
    options.inter_op_num_threads = SESSION_SETTINGS["inter_op_num_threads"]
    options.execution_mode = getattr(onnxruntime.ExecutionMode, SESSION_SETTINGS["execution_mode"])
    options.graph_optimization_level = getattr(
        onnxruntime.GraphOptimizationLevel, SESSION_SETTINGS["graph_optimization_level"]
    )
    options.log_severity_level = 3  # errors only: warnings would go to every job's log
    try:
        return onnxruntime.InferenceSession(
            str(onnx_file), sess_options=options, providers=SESSION_SETTINGS["providers"]
        )
    except Exception as err:  # noqa: BLE001 - onnxruntime raises its own classes
        too_new = _IR_TOO_NEW.search(str(err))
        if too_new:
            version, most = too_new.groups()
            raise PolicyFileError(
                f"{onnx_file}: IR version {version}, newer than onnxruntime "
                f"{onnxruntime.__version__} reads (at most {most}); export with an IR version "
                f"<= {most}, e.g. onnx.helper.make_model(..., ir_version=10)"
            ) from None
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise PolicyFileError(f"{onnx_file}: onnxruntime cannot load it: {first}") from None


def _check_tensor(where: Path, kind: str, arg: Any, width: int, what: str) -> None:
    """A graph input or output of shape (batch, width), float32, its batch dimension dynamic."""
    shape = list(arg.shape)
    if arg.type != _FLOAT32:
        raise PolicyFileError(
            f"{where}: graph {kind} {arg.name!r} is {arg.type}; expected float32 (tensor(float))"
        )
    if len(shape) != 2:
        raise PolicyFileError(
            f"{where}: graph {kind} {arg.name!r} has shape {shape}; expected (batch, {width})"
        )
    if isinstance(shape[0], int):
        raise PolicyFileError(
            f"{where}: graph {kind} {arg.name!r} has a fixed batch dimension {shape[0]}; "
            "expected a dynamic one (a symbolic dim such as 'batch')"
        )
    if isinstance(shape[1], int) and shape[1] != width:
        raise PolicyFileError(
            f"{where}: graph {kind} {arg.name!r} has {shape[1]} columns; expected {width} ({what})"
        )


def check_graph(
    contract: Contract, session: onnxruntime.InferenceSession, onnx_file: Path, n_columns: int
) -> None:
    """The graph's inputs and outputs against the contract: names, shapes, dtypes, a dynamic
    batch dimension; then zero batches of `PROBE_ROWS` rows run through it for the shapes a
    graph leaves symbolic (a shape that changes with the batch's size is also checked at every
    call: `OnnxPolicy`)."""
    inputs = {a.name: a for a in session.get_inputs()}
    outputs = {a.name: a for a in session.get_outputs()}
    fed = {contract.input: (n_columns, f"the {n_columns} observation column(s)")}
    read = {
        contract.output: (
            contract.n_outputs,
            "one per actuator entry of the contract, 3 per mocap body",
        )
    }
    for r in contract.recurrent:
        fed[r.input] = read[r.output] = (r.size, "the recurrent state's size")
    for name, (width, what) in fed.items():
        if name not in inputs:
            raise PolicyFileError(
                f"{contract.source}: input {name!r} is not an input of {onnx_file} "
                f"(its inputs: {sorted(inputs)})"
            )
        _check_tensor(onnx_file, "input", inputs[name], width, what)
    unfed = sorted(set(inputs) - set(fed))
    if unfed:
        raise PolicyFileError(
            f"{contract.source}: {onnx_file} has input(s) {unfed} that the contract does not feed; "
            "expected them as its input or a recurrent state's input"
        )
    for name, (width, what) in read.items():
        if name not in outputs:
            raise PolicyFileError(
                f"{contract.source}: output {name!r} is not an output of {onnx_file} "
                f"(its outputs: {sorted(outputs)})"
            )
        _check_tensor(onnx_file, "output", outputs[name], width, what)
    for rows in PROBE_ROWS:
        feeds = {n: np.zeros((rows, width), dtype=np.float32) for n, (width, _) in fed.items()}
        try:
            answers = session.run(list(read), feeds)
        except Exception as err:  # noqa: BLE001 - onnxruntime raises its own classes
            first = str(err).strip().splitlines()[0]
            raise PolicyFileError(
                f"{onnx_file}: a batch of {rows} zero rows failed: {first}"
            ) from None
        for (name, (width, what)), value in zip(read.items(), answers, strict=True):
            if value.shape != (rows, width) or value.dtype != np.float32:
                raise PolicyFileError(
                    f"{onnx_file}: output {name!r} of a batch of {rows} rows has shape "
                    f"{value.shape} and dtype {value.dtype}; expected ({rows}, {width}) float32 "
                    f"({what})"
                )


class OnnxPolicy:
    """A `closed_loop.BatchPolicy` running a policy file's graph on the whole batch, one
    onnxruntime call per control instant (recurrent state included).

    Observations are normalized in float64, then cast to float32 for the graph; the action is
    scaled in float64 and clipped to each ctrllimited actuator's range (what MuJoCo applies, and
    so what the recordings show), `raw` actions too. A row whose action is not finite gets
    ctrl 0 from then on, and `failed_episodes()` marks it (the engine's `NONFINITE_ACTION`).
    The last `n_mocap` columns (a contract's mocap bodies) are given as they are, after the
    actuators' columns.
    """

    def __init__(
        self,
        session: onnxruntime.InferenceSession,
        contract: Contract,
        *,
        columns: np.ndarray,
        ctrl_range: np.ndarray,
        nu: int,
        n_mocap: int = 0,
        graph: Path | None = None,
    ) -> None:
        self.session, self.contract = session, contract
        self.graph = graph or contract.source  # the file an error names
        self.columns = np.asarray(columns, dtype=np.int64)  # the ctrl column of each output
        self.low, self.high = np.asarray(ctrl_range, dtype=np.float64).T  # (k,) each
        self.half_span = (self.high - self.low) / 2.0
        # a column relative to its joints is a step from their positions: given raw, and its
        # ctrl clipped (by MuJoCo) only once the positions are added (`mjtrial.sim.actuation`)
        self.absolute = np.array([not isinstance(a, RelativeColumn) for a in contract.actuators])
        self.nu, self.n_mocap = nu, n_mocap
        self.outputs = [contract.output, *(r.output for r in contract.recurrent)]
        self.widths = [contract.n_outputs, *(r.size for r in contract.recurrent)]
        self.state: dict[str, np.ndarray] = {}
        self.failed = np.zeros(0, dtype=bool)

    def reset(self, n_episodes: int) -> None:
        self.state = {
            r.input: np.zeros((n_episodes, r.size), dtype=np.float32)
            for r in self.contract.recurrent
        }
        self.failed = np.zeros(n_episodes, dtype=bool)

    def _graph_input(self, observations: np.ndarray) -> np.ndarray:
        """Observations as the graph takes them: normalized in float64, then float32."""
        x = np.asarray(observations, dtype=np.float64)
        if self.contract.mean is not None:
            x = (x - self.contract.mean) / self.contract.std
        return x.astype(np.float32)

    def _run(self, x: np.ndarray, state: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        """The graph on rows `x` (float32) and the recurrent state: its outputs, each checked
        at every call (`check_graph`'s probe of 2 rows cannot see a shape that changes with the
        batch, and a recurrent state that grows would grow each call)."""
        answers = self.session.run(self.outputs, {self.contract.input: x, **state})
        for name, width, value in zip(self.outputs, self.widths, answers, strict=True):
            if value.shape != (len(x), width):
                raise PolicyFileError(
                    f"{self.graph}: output {name!r} of a batch of {len(x)} rows has shape "
                    f"{value.shape}; expected ({len(x)}, {width}), one row per episode"
                )
        return answers

    def _controls(self, raw: np.ndarray, failed: np.ndarray) -> np.ndarray:
        """The ctrl of each row of the graph's actions `raw`, 0 where `failed` (elementwise
        arithmetic only: a row's ctrl is the same bits whatever rows come with it)."""
        action = raw.astype(np.float64)
        moved = action[:, action.shape[1] - self.n_mocap :]
        action = action[:, : action.shape[1] - self.n_mocap]
        absolute = self.absolute
        if self.contract.action_scale == "ctrlrange":
            action[:, absolute] = (
                self.low[absolute] + (action[:, absolute] + 1.0) * self.half_span[absolute]
            )
        # clipped as MuJoCo clamps a ctrllimited actuator: the ctrl logged is the ctrl applied
        action[:, absolute] = np.minimum(
            np.maximum(action[:, absolute], self.low[absolute]), self.high[absolute]
        )
        ctrl = np.zeros((len(raw), self.nu))
        ctrl[:, self.columns] = action
        if self.n_mocap:
            ctrl[:, self.nu - self.n_mocap :] = moved
        if failed.any():
            ctrl[failed] = 0.0
        return ctrl

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        if len(observations) != len(self.failed):
            raise ValueError(
                f"expected {len(self.failed)} rows (the reset's), got {len(observations)}"
            )
        answers = self._run(self._graph_input(observations), self.state)
        for r, value in zip(self.contract.recurrent, answers[1:], strict=True):
            self.state[r.input] = value
        finite = np.isfinite(answers[0])
        if not finite.all():
            self.failed |= ~finite.all(axis=1)
        return self._controls(answers[0], self.failed)

    def alone(self, observations: np.ndarray) -> np.ndarray:
        """The controls one episode gets alone, from a reset, at each of its instants:
        `observations` (k, n_observations) -> (k, nu), what `reset(1)` and k calls give, bit
        for bit. The graph runs on the episode's row alone at every instant (the replay's exact
        check, `closed_loop.check_replayed`); the arithmetic around it, elementwise, runs on
        all k instants at once: per call, it cost 2.5 times the graph's own 11 µs
        (benchmarks/bench_policy_file.py). The graph's row is bound once (`one_row.OneRow`)."""
        x = self._graph_input(observations)
        one = OneRow(self.session, self.contract, x.shape[1], self.outputs, self.widths)
        raw = np.empty((len(x), self.contract.n_outputs), dtype=np.float32)
        for k in range(len(x)):
            try:
                raw[k] = one(x[k])
            except Exception:  # an output of another shape: the checked call says which
                self._run(x[k : k + 1].copy(), {n: a.copy() for n, a in one.state.items()})
                raise
        failed = np.logical_or.accumulate(~np.isfinite(raw).all(axis=1))
        return self._controls(raw, failed)

    def failed_episodes(self) -> np.ndarray:
        """(n_episodes,) True where an action was non-finite since the reset."""
        return self.failed.copy()


@dataclass(frozen=True)
class PolicyFile:
    """A policy file checked against a task: what a condition that names it runs.

    Attributes:
      path: the `.onnx` file.
      contract: its contract, as read.
      sha256: the `.onnx` file's sha256 (the contract's is `contract_sha256`).
      observations: the task's observations it reads, in input order.
      settings: onnxruntime's version and the session settings, as the stamps record them.
    """

    path: Path
    contract: Contract
    sha256: str
    contract_sha256: str
    task: Task
    session: onnxruntime.InferenceSession = dataclasses.field(repr=False, compare=False)
    data: tuple[Path, ...] = ()  # the graph's external data files (`data_files`)

    @property
    def observations(self) -> tuple[str, ...]:
        return self.contract.observations

    @property
    def settings(self) -> dict[str, Any]:
        return runtime_settings()

    @property
    def files(self) -> list[Path]:
        """The files it is made of (graph, contract, external data): the inputs of a stamp
        that used it."""
        return [self.path, self.contract.source, *self.data]

    def policy(self, model: mujoco.MjModel, params: Mapping[str, float]) -> OnnxPolicy:
        """The batch policy under a condition: its actuators and control period checked
        against the model and the task's timing (`PolicyFileError`, one line)."""
        where = self.contract.source
        timing = self.task.controller.timing(model, params)
        period = timing.steps_per_control * model.opt.timestep
        if abs(period - self.contract.control_period) > 1e-9:
            raise PolicyFileError(
                f"{where}: control_period {self.contract.control_period:g} s; expected the "
                f"task's, {period:g} s, under this condition"
            )
        columns, ranges = [], []
        for k, entry in enumerate(self.contract.actuators):
            relative = isinstance(entry, RelativeColumn)
            names = entry.actuators if relative else (entry,) if isinstance(entry, str) else entry
            indices = []
            for name in names:
                try:  # a name, or an unnamed actuator's `#<index>` / `on:<joint>` (`address`)
                    index = address.resolve(model, "actuator", name)
                except address.AddressError as err:
                    known = [address.describe(model, "actuator", i) for i in range(model.nu)]
                    raise PolicyFileError(
                        f"{where}: actuators: {name!r}: {err} (its actuators: {known})"
                    ) from None
                if (
                    self.contract.action_scale == "ctrlrange"
                    and not relative
                    and not model.actuator_ctrllimited[index]
                ):
                    raise PolicyFileError(
                        f"{where}: action_scale ctrlrange: actuator {name!r} has no ctrlrange; "
                        "expected a ctrllimited actuator, or action_scale raw"
                    )
                indices.append(index)
            # raw: clipped to a ctrllimited actuator's range, as MuJoCo would (unlimited: as is)
            limited = model.actuator_ctrllimited[indices].astype(bool)[:, None] & (not relative)
            own = np.where(limited, model.actuator_ctrlrange[indices], [-np.inf, np.inf])
            # the column's range: each actuator's divided by its sign ([a, -a] jaws whose
            # ranges are [0, 0.04] and [-0.04, 0] share [0, 0.04])
            signs = np.array(self.contract.signs_of(k) or [1] * len(indices))[:, None]
            own = np.sort(own * signs, axis=1)
            if not (own == own[0]).all():
                signed = " times their signs" if self.contract.signs_of(k) else ""
                raise PolicyFileError(
                    f"{where}: actuators: {list(names)} driven by one column have different "
                    f"ctrlranges{signed}; expected one range for the column"
                )
            columns.append(indices[0])
            ranges.append(own[0])
        actions = self.contract.actions
        n_mocap = 3 * len(self.contract.mocap)
        return OnnxPolicy(
            self.session,
            self.contract,
            # with actions, the policy's answer is the output's columns themselves
            columns=np.arange(len(columns)) if actions else np.array(columns),
            ctrl_range=np.array(ranges).reshape(len(columns), 2),
            nu=self.contract.n_outputs if actions else model.nu,
            n_mocap=n_mocap,
            graph=self.path,
        )


def load_policy_file(path: str | Path, task: Task) -> PolicyFile:
    """A policy file and its contract, checked against the task (its name, its declared
    observations, a closed-loop controller) and against the graph (names, shapes, dtypes, a
    dynamic batch dimension). Raises `PolicyFileError`, one line naming the file."""
    path = Path(path)
    if path.suffix != ".onnx" or not path.is_file():
        raise PolicyFileError(f"{path}: expected an existing .onnx file")
    contract = read_contract(path)
    where = contract.source
    if not isinstance(task.controller, ClosedLoop):
        raise PolicyFileError(
            f"{where}: task {task.name!r} is open loop; expected a closed-loop task"
        )
    if contract.task != task.name:
        raise PolicyFileError(f"{where}: task {contract.task!r}; expected {task.name!r}")
    declared = {o.name: o for o in task.observations}
    for name in contract.observations:
        if name not in declared:
            raise PolicyFileError(
                f"{where}: observations: {name!r} is not an observation of task {task.name!r} "
                f"(declared: {sorted(declared)})"
            )
    n_columns = sum(_widths(task, contract.observations, where))
    for key in ("mean", "std"):
        values = getattr(contract, key)
        if values is not None and values.shape != (n_columns,):
            raise PolicyFileError(
                f"{where}: normalization.{key}: {len(values)} numbers; expected {n_columns}, "
                "one per observation column"
            )
    data = data_files(path)
    session = open_session(path)
    check_graph(contract, session, path, n_columns)
    return PolicyFile(
        path, contract, file_sha256(path), file_sha256(where), task, session, tuple(data)
    )


def _widths(task: Task, names: Sequence[str], where: Path) -> list[int]:
    """Each observation's number of columns: a sensor's is its dimension in the task's model
    (a `framepos` has 3), loaded only for one."""
    declared = {o.name: o for o in task.observations}
    model = None
    if any(declared[n].sensor_name is not None for n in names):
        try:
            model = load_model(task.model)
            return [declared[n].columns(model) for n in names]
        except (ModelError, TaskError) as err:
            raise PolicyFileError(f"{where}: observations: {err}") from None
    return [declared[n].size for n in names]


def policy_task(task: Task, policy_file: PolicyFile) -> Task:
    """The task with the policy file as its controller's policy, reading the contract's
    observations (the task's timing and pushes unchanged)."""
    controller = task.controller
    assert isinstance(controller, ClosedLoop)  # load_policy_file checked it
    return dataclasses.replace(
        task,
        controller=dataclasses.replace(
            controller,
            policy=policy_file.policy,
            observations=policy_file.observations,
            source=policy_file.contract.source,
            actions=policy_file.contract.actions,
        ),
    )


def policy_inputs(paths: Sequence[str | Path]) -> dict[str, Any]:
    """A stamp's record of the policy files a stage ran: each graph with its contract and its
    external data files."""
    files = [f for p in paths for f in policy_file_paths(p)]
    return {"policy": files} if files else {}
