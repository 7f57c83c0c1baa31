"""One function per pipeline stage: what a Snakemake script calls, importable and testable.

Each stage reads its inputs, computes, and writes its outputs atomically with a provenance
stamp; none of them knows about Snakemake.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, analysis, provenance, taxonomy
from mjtrial.protocol import PROTOCOL, control_sequence
from mjtrial.simulate import (
    CUBE_BODY,
    EPISODE_COLUMNS,
    EpisodeBatch,
    InitialState,
    episode_outcomes,
    iter_episode_batches,
    load_model,
)
from mjtrial.states import generate_initial_states, states_from_table

log = logging.getLogger("mjtrial")

# The package modules each stage runs: their source hash goes into the rule's params, so a
# real code change reruns the stage and a checkout that leaves the code alone does not.
STAGE_MODULES: dict[str, tuple[str, ...]] = {
    "states": ("mjtrial.pipeline", "mjtrial.states", "mjtrial.provenance", "mjtrial.atomic"),
    "rollout": (
        "mjtrial.pipeline",
        "mjtrial.states",
        "mjtrial.simulate",
        "mjtrial.protocol",
        "mjtrial.taxonomy",
        "mjtrial.recording",
        "mjtrial.provenance",
        "mjtrial.atomic",
    ),
    "analysis": (
        "mjtrial.pipeline",
        "mjtrial.analysis",
        "mjtrial.stats",
        "mjtrial.provenance",
        "mjtrial.atomic",
    ),
    "failures": ("mjtrial.pipeline", "mjtrial.recording", "mjtrial.provenance", "mjtrial.atomic"),
    "manifest": ("mjtrial.pipeline", "mjtrial.provenance", "mjtrial.atomic"),
    "report": (
        "mjtrial.pipeline",
        "mjtrial.report",
        "mjtrial.simulate",
        "mjtrial.protocol",
        "mjtrial.provenance",
        "mjtrial.atomic",
    ),
}


def config_slice(
    stage: str, config: Mapping[str, Any], *, condition: str | None = None
) -> dict[str, Any]:
    """The part of the config a stage depends on: its rule's params and its stamp's record.

    Changing a value outside a stage's slice never reruns that stage.
    """
    if stage == "states":
        return dict(config["states"])
    if stage == "rollout":
        return {
            "condition": condition,
            **config["conditions"][condition],
            "failure_taxonomy": dict(config["failure_taxonomy"]),
            "recording": dict(config["recording"]),
        }
    if stage == "analysis":
        return {
            "conditions": dict(config["conditions"]),
            "falsifier": dict(config["design"]["falsifier"]),
            "sample_size": dict(config["design"]["sample_size"]),
            "analysis": dict(config["analysis"]),
        }
    if stage in ("manifest", "report"):
        return dict(config)
    raise ValueError(f"stage: expected one of {sorted(STAGE_MODULES)}, got {stage!r}")


def model_inputs(model_file: Path) -> dict[str, Any]:
    """A stamp's record of the model: the scene, and the other files it is built from."""
    scene, *included = provenance.model_files(model_file)
    return {"model": scene, "model_files": included}


def stage_code_hash(stage: str) -> str:
    """sha256 of the source of the modules `stage` runs."""
    return provenance.code_hash(STAGE_MODULES[stage])


def _stamp(
    rule: str,
    config_slice: Any,
    inputs: Mapping[str, Any],
    *,
    seeds: Mapping[str, int] | None = None,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    return provenance.make_stamp(
        rule=rule,
        config_slice=config_slice,
        inputs={k: v for k, v in inputs.items()},
        seeds=seeds,
        repo_dir=repo_root,
        extra={"code_sha256": stage_code_hash(rule.split(":")[0])},
    )


def build_states(
    *,
    states_slice: Mapping[str, Any],
    output: Path,
    development: bool = False,
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """Draw the evaluation states (or, with `development`, the tuning states) and write them.

    Both sets are drawn, to refuse a configuration whose development and evaluation states
    share a state: no reported number may come from a state used for tuning.
    """
    table = generate_initial_states(
        seed=states_slice["seed"], n=states_slice["n"], ranges=states_slice["ranges"]
    )
    tuning = generate_initial_states(
        seed=states_slice["development_seed"], n=states_slice["n"], ranges=states_slice["ranges"]
    )
    rows = {
        tuple(r) for r in np.column_stack([table.column(c) for c in ("dx", "dy", "yaw", "mass")])
    }
    dev_rows = np.column_stack([tuning.column(c) for c in ("dx", "dy", "yaw", "mass")])
    if any(tuple(r) in rows for r in dev_rows):
        raise ValueError(
            "states.development_seed: development and evaluation states overlap; "
            "expected disjoint seeds"
        )
    stamp = _stamp(
        "states:development" if development else "states",
        dict(states_slice),
        {},
        seeds={"states": states_slice["seed"], "development": states_slice["development_seed"]},
        repo_root=repo_root,
    )
    chosen, seed = (tuning, "development_seed") if development else (table, "seed")
    provenance.write_parquet(chosen, output, stamp)
    log.info(
        "states: %d %s states (seed %d) -> %s",
        chosen.num_rows,
        "development" if development else "evaluation",
        states_slice[seed],
        output,
    )
    return chosen


def read_states(path: Path) -> list[InitialState]:
    """The initial states stored in `states.parquet`, checked."""
    return states_from_table(pq.read_table(path), source=str(path))


def nominal_state(model: Any) -> InitialState:
    """The state a careless evaluation uses alone: no offset, no yaw, the mass as compiled."""
    import mujoco

    cube = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, CUBE_BODY)
    return InitialState(-1, 0.0, 0.0, 0.0, float(model.body_mass[cube]))


# Columns of `rollouts/<condition>.parquet`, in order: the outcome, then the failure analysis.
ROLLOUT_COLUMNS = (*EPISODE_COLUMNS, "failure_category", "peak_slip", "peak_carriage_accel")


def condition_outcomes(
    model: Any,
    states: Sequence[InitialState],
    *,
    lift_time: float,
    thresholds: taxonomy.Thresholds,
    nthread: int,
    batch_size: int = 64,
) -> Iterator[tuple[EpisodeBatch, dict[str, np.ndarray]]]:
    """Each batch of episodes with its per-episode columns (`ROLLOUT_COLUMNS`)."""
    _, phase = control_sequence(lift_time, timestep=model.opt.timestep)
    for batch in iter_episode_batches(
        model, states, lift_time=lift_time, nthread=nthread, batch_size=batch_size
    ):
        outcome = episode_outcomes(model, batch, lift_time=lift_time)
        traj = taxonomy.trajectories_from_batch(
            model, batch, phase=phase, home_xy=(PROTOCOL.home_x, 0.0)
        )
        yield batch, outcome | taxonomy.classify(traj, outcome["success"], thresholds)


def log_every(rate_hz: float, timestep: float) -> int:
    """Physics steps between logged steps for a logging rate (at least every step)."""
    return max(1, round(1.0 / (rate_hz * timestep)))


def episode_records(batch: EpisodeBatch, outcome: Mapping[str, np.ndarray]) -> Iterator[Any]:
    """The batch's episodes as `recording.EpisodeRecord`s, with their outcomes."""
    from mjtrial.recording import EpisodeRecord

    for i, state in enumerate(batch.states):
        yield EpisodeRecord(
            state=state,
            physics=batch.physics[i],
            sensordata=batch.sensordata[i],
            success=bool(outcome["success"][i]),
            final_height=float(outcome["final_height"][i]),
            failure_category=outcome["failure_category"][i],
        )


def run_condition(
    *,
    condition_slice: Mapping[str, Any],
    states_path: Path,
    model_file: Path,
    output_table: Path,
    output_nominal: Path,
    output_recording: Path | None = None,
    nthread: int,
    batch_size: int = 64,
    repo_root: Path = REPO_ROOT,
) -> dict[str, np.ndarray]:
    """Roll out every state under one condition.

    Writes the per-episode table, the nominal state's episode, and (given `output_recording`,
    a folder) every episode's trajectory as a Rerun recording, one .rrd per episode, written
    batch by batch while the next batch runs.
    """
    from mjtrial import recording

    model = load_model(model_file)
    states = read_states(states_path)
    condition = condition_slice["condition"]
    lift_time = float(condition_slice["lift_time"])
    thresholds = taxonomy.Thresholds.from_config(condition_slice["failure_taxonomy"])
    inputs = {"states": states_path, **model_inputs(model_file)}
    stamp = _stamp(f"rollout:{condition}", dict(condition_slice), inputs, repo_root=repo_root)
    columns: dict[str, list[np.ndarray]] = {c: [] for c in ROLLOUT_COLUMNS}

    def episodes() -> Iterator[recording.EpisodeRecord]:
        for batch, outcome in condition_outcomes(
            model,
            states,
            lift_time=lift_time,
            thresholds=thresholds,
            nthread=nthread,
            batch_size=batch_size,
        ):
            for c in ROLLOUT_COLUMNS:
                columns[c].append(outcome[c])
            yield from episode_records(batch, outcome)

    if output_recording is None:
        for _ in episodes():
            pass
    else:
        recording.write_condition_recordings(
            output_recording,
            model=model,
            condition=condition,
            episodes=episodes(),
            ctrl=control_sequence(lift_time, timestep=model.opt.timestep)[0],
            stamp=stamp,
            log_every=log_every(condition_slice["recording"]["rate_hz"], model.opt.timestep),
        )
    merged = {c: np.concatenate(v) for c, v in columns.items()}
    table = pa.table(
        {
            c: pa.array(merged[c].tolist() if merged[c].dtype == object else merged[c])
            for c in ROLLOUT_COLUMNS
        }
    )
    nominal = nominal_state(model)
    _, nominal_outcome = next(
        condition_outcomes(model, [nominal], lift_time=lift_time, thresholds=thresholds, nthread=1)
    )

    provenance.write_parquet(table, output_table, stamp)
    provenance.write_json(
        {
            "condition": condition,
            "state": nominal.__dict__ | {"state_id": None},
            "success": bool(nominal_outcome["success"][0]),
            "final_height": float(nominal_outcome["final_height"][0]),
            "failure_category": nominal_outcome["failure_category"][0],
        },
        output_nominal,
        stamp,
    )
    log.info(
        "rollout %s: %d/%d successes (lift %g s) -> %s",
        condition,
        int(merged["success"].sum()),
        len(states),
        lift_time,
        output_table,
    )
    return merged


def run_analysis(
    *,
    states_path: Path,
    rollout_tables: Mapping[str, Path],
    nominal_files: Mapping[str, Path],
    analysis_slice: Mapping[str, Any],
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """Compute the summary, write `summary.json`, and log the table."""
    conditions = analysis_slice["conditions"]
    analysis_config = analysis_slice["analysis"]
    states_table = pq.read_table(states_path)
    states = {c: states_table.column(c).to_numpy() for c in states_table.column_names}
    outcomes = {}
    for name, path in rollout_tables.items():
        t = pq.read_table(path)
        outcomes[name] = {c: t.column(c).to_numpy(zero_copy_only=False) for c in t.column_names}
    nominal = {
        name: bool(json.loads(Path(p).read_text())["success"]) for name, p in nominal_files.items()
    }
    summary = analysis.summarize(
        states=states,
        outcomes=outcomes,
        nominal=nominal,
        lift_times={name: float(c["lift_time"]) for name, c in conditions.items()},
        falsifier=analysis_slice["falsifier"],
        analysis=analysis_config,
        sample_size=analysis_slice.get("sample_size"),
    )
    inputs = {"states": states_path, **{f"rollout:{k}": v for k, v in rollout_tables.items()}}
    inputs |= {f"nominal:{k}": v for k, v in nominal_files.items()}
    stamp = _stamp(
        "analysis",
        dict(analysis_slice),
        inputs,
        seeds={"bootstrap": analysis_config["seed"]},
        repo_root=repo_root,
    )
    provenance.write_json(summary, output, stamp)
    log.info("analysis -> %s\n%s", output, analysis.format_table(summary))
    return summary


def gather_failures(
    *,
    recordings: Sequence[Path],
    tables: Sequence[Path],
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> int:
    """Gather every failed episode of every condition into one `failures.rrd`.

    `recordings` are the conditions' folders (`rollouts/<condition>/`), `tables` their rollout
    tables, in the same order: the tables say which episodes failed, so only their files are
    opened (at 100 000 states, opening every file would take minutes); a recording that does
    not say it failed is an error (`recording.write_failures_rrd`'s `only_failures`).
    """
    from mjtrial import recording

    if len(recordings) != len(tables):
        raise ValueError(f"{len(recordings)} recording folders but {len(tables)} tables")
    files = []
    for folder, table in zip(map(Path, recordings), map(Path, tables), strict=True):
        rows = pq.read_table(table, columns=["state_id", "success"]).to_pylist()
        files += [
            folder / recording.episode_file_name(folder.name, row["state_id"])
            for row in rows
            if not row["success"]
        ]
    inputs = {p.stem: p for p in recordings} | {f"{p.stem}_table": p for p in tables}
    stamp = _stamp("failures", {}, inputs, repo_root=repo_root)
    count = recording.write_failures_rrd(output, files, stamp=stamp, only_failures=True)
    log.info("failures: %d failed episodes -> %s", count, output)
    return count


def write_manifest(
    *,
    config: Mapping[str, Any],
    summary_path: Path,
    outputs: Sequence[Path],
    model_file: Path,
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """Gather the reproducibility record and the stamp of every output into `manifest.json`."""
    import mujoco

    model = load_model(model_file)
    summary = json.loads(Path(summary_path).read_text())

    def rel(path: Path) -> str:
        path = Path(path).resolve()
        try:
            return path.relative_to(repo_root.resolve()).as_posix()
        except ValueError:
            return path.name

    stamps = {rel(p): provenance.read_stamp(p) for p in [*outputs, summary_path]}
    manifest = {
        "experiment": config["experiment"],
        "design": config["design"],
        "rerun": {
            "command": "snakemake -c2",
            "config": dict(config),
            "commit": next(iter(stamps.values()))["git"].get("commit"),
        },
        "versions": provenance.library_versions(),
        "model": {
            "path": config["model"],
            "sha256": provenance.model_sha256(model_file),
            "files": {
                p.relative_to(model_file.parent).as_posix(): provenance.file_sha256(p)
                for p in provenance.model_files(model_file)
            },
            "timestep": model.opt.timestep,
            "integrator": mujoco.mjtIntegrator(model.opt.integrator).name,
            "cone": mujoco.mjtCone(model.opt.cone).name,
            "impratio": model.opt.impratio,
        },
        "seeds": {
            "states": config["states"]["seed"],
            "development": config["states"]["development_seed"],
            "bootstrap": config["analysis"]["seed"],
        },
        "n_states": config["states"]["n"],
        "randomization_ranges": config["states"]["ranges"],
        "success_definition": {
            "cube_height_above_m": PROTOCOL.success_height,
            "judged": f"at the end of the {PROTOCOL.hold_time:g} s hold after the lift",
        },
        "results": {
            "conditions": {
                name: {"successes": rec["successes"], "n": rec["n"], "rate": rec["rate"]}
                for name, rec in summary["conditions"].items()
            },
            "paired_difference": summary["paired_difference"],
            "falsifier": summary["falsifier"],
        },
        "stamps": stamps,
    }
    stamp = _stamp(
        "manifest",
        dict(config),
        {rel(p): p for p in [*outputs, summary_path]},
        repo_root=repo_root,
    )
    provenance.write_json(manifest, output, stamp)
    log.info("manifest -> %s", output)
    return manifest


def write_report_stage(
    *,
    config: Mapping[str, Any],
    summary_path: Path,
    manifest_path: Path,
    states_path: Path,
    rollout_tables: Mapping[str, Path],
    model_file: Path,
    figures_dir: Path,
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> list[Path]:
    """Draw the figures and write `report.md`; every number in them comes from the inputs."""
    from mjtrial import report

    inputs = {
        "summary": summary_path,
        "manifest": manifest_path,
        "states": states_path,
        **model_inputs(model_file),
        **{f"rollout:{k}": v for k, v in rollout_tables.items()},
    }
    stamp = _stamp("report", dict(config), inputs, repo_root=repo_root)
    summary = json.loads(Path(summary_path).read_text())
    figures = report.write_figures(
        summary=summary,
        states_path=states_path,
        rollout_tables=rollout_tables,
        model_file=model_file,
        lift_times={name: float(c["lift_time"]) for name, c in config["conditions"].items()},
        out_dir=figures_dir,
        stamp=stamp,
    )
    report.write_report(
        summary_path=summary_path,
        config=dict(config),
        manifest_path=manifest_path,
        figure_paths=figures,
        output=output,
        stamp=stamp,
        repo_root=repo_root,
    )
    log.info("report -> %s (%d figure files)", output, len(figures))
    return figures
