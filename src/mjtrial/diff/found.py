"""What differs in what two runs found: their outputs' content, each condition's success on the
states both ran (McNemar's exact test on the pairs), the main effect and the falsifier's verdict,
the same for each variant of the sensitivity study."""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from mjtrial import provenance, stats
from mjtrial.diff.registration import without_registration_time
from mjtrial.diff.source import Run
from mjtrial.files.layout import NOMINAL, BenchmarkLayout

# Where the seal lists a rollout table: `rollouts/<condition>.parquet`, or a variant's.
_ROLLOUT_TABLE = re.compile(
    r"(?:variants/(?P<variant>[^/]+)/)?rollouts/(?P<condition>[^/]+)\.parquet"
)
# A benchmark's evaluation of one training seed's parameters on a task's evaluation states.
_EVALUATION = re.compile(
    r"evaluation/(?P<task>[^/]+)/(?P<method>[^/]+)/seed-(?P<seed>[^/]+)\.parquet"
)
# An output compared by outcomes and trajectories, not bytes: a recording (its bytes hold its
# stamp) or a folder of them.
_RECORDING = re.compile(r".*\.rrd|.*/shard-\d+")


# -- outputs ---------------------------------------------------------------------------------


def _content(run: Run, rel: str) -> bytes | None:
    """The output's content less its stamp (`provenance.content_without_stamp`); a manifest
    also less its copies of every output's stamp; and less when the design was registered
    (`registration.without_registration_time`): a record of the run, as a stamp is, so two
    builds of one commit compare the same (the registered design itself is compared)."""
    content = provenance.content_without_stamp(run.root / rel)
    if content is None:
        return None
    if rel == run.layout.manifest.name:
        obj = json.loads(content)
        obj.pop("stamps", None)
        content = json.dumps(obj, sort_keys=True).encode()
    return without_registration_time(run, rel, content)


def not_as_sealed(run: Run) -> dict[str, list[str]]:
    """The run's sealed outputs that are not what it sealed: `missing` (gone from the folder),
    `altered` (its bytes are not the sha256 its seal records) and `rows` (a table whose rows
    are not the ones its own stamp records, `provenance.rows_problem`: edited, then sealed
    again). A diff compares what is on disk; the seals say what the run was."""
    out: dict[str, list[str]] = {"missing": [], "altered": [], "rows": []}
    for rel, sealed in run.outputs.items():
        now = run.disk_sha256(rel)
        if now is None:
            out["missing"].append(rel)
        elif now != sealed:
            out["altered"].append(rel)
        elif rel.endswith(".parquet") and provenance.rows_problem(run.root / rel):
            out["rows"].append(rel)
    return out


def compare_outputs(a: Run, b: Run) -> dict[str, list[str]]:
    """Every sealed output, relative to its results folder, by what the comparison found:
    `only_a`, `only_b`; `same` (the same sha256 in both seals and on both disks);
    `same_content` (bytes differ in the stamp alone: another build of the same result);
    `differ`; `recordings` (Rerun recordings and their folders: bytes hold stamps, so they are
    compared through the rollout tables' outcomes and measures, and by trajectory where an
    outcome flipped); and per run (`_a`, `_b`) what is not as it sealed (`not_as_sealed`):
    `missing_*`, `altered_*`, `rows_*`. An output not as sealed in either run is in no other
    list but `only_*`: what it was is not there to compare."""
    out: dict[str, list[str]] = {
        k: [] for k in ("only_a", "only_b", "same", "same_content", "differ", "recordings")
    }
    broken: set[str] = set()
    for run, side in ((a, "a"), (b, "b")):
        for kind, rels in not_as_sealed(run).items():
            out[f"{kind}_{side}"] = rels
            broken.update(rels)
    out["only_a"] = sorted(set(a.outputs) - set(b.outputs))
    out["only_b"] = sorted(set(b.outputs) - set(a.outputs))
    for rel in sorted(set(a.outputs) & set(b.outputs) - broken):
        if a.outputs[rel] == b.outputs[rel]:
            out["same"].append(rel)
        elif _RECORDING.fullmatch(rel):
            out["recordings"].append(rel)
        elif _content(a, rel) == _content(b, rel) is not None:
            out["same_content"].append(rel)
        else:
            out["differ"].append(rel)
    return out


# -- conditions ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Outcomes:
    """One rollout table's outcomes, by row: `state_id` (n,), `success` (n,),
    `failure_category` (n,) (None where it succeeded)."""

    state_id: np.ndarray
    success: np.ndarray
    failure_category: np.ndarray


def rollout_groups(run: Run) -> dict[str, tuple[str, str]]:
    """{group: (its table of outcomes, its states)}: a condition (`<condition>`), a variant's
    (`<variant>/<condition>`), or a benchmark's evaluation of a method's training seed on a
    task (`<task>/<method>/seed-<seed>`)."""
    out = {}
    for rel in run.outputs:
        if m := _ROLLOUT_TABLE.fullmatch(rel):
            variant = m.group("variant") or NOMINAL
            group = m.group("condition") if variant == NOMINAL else f"{variant}/{m['condition']}"
            out[group] = (rel, run.layout.states.name)
        elif m := _EVALUATION.fullmatch(rel):
            states = BenchmarkLayout(run.root).task(m["task"]).states
            out[f"{m['task']}/{m['method']}/seed-{m['seed']}"] = (
                rel,
                states.relative_to(run.root).as_posix(),
            )
    return out


def read_outcomes(run: Run, rel: str) -> Outcomes:
    """The table's outcomes, in state order."""
    table = pq.read_table(run.root / rel, columns=["state_id", "success", "failure_category"])
    state_id = table.column("state_id").to_numpy()
    order = np.argsort(state_id, kind="stable")
    return Outcomes(
        state_id=state_id[order],
        success=table.column("success").to_numpy(zero_copy_only=False).astype(bool)[order],
        failure_category=np.asarray(table.column("failure_category").to_pylist(), dtype=object)[
            order
        ],
    )


def shared_states(a: Run, b: Run, states: str) -> np.ndarray:
    """The state ids both runs drew with the same values (sorted) in their table `states`
    (relative to the results folder): only these are paired."""
    if not all((r.root / states).is_file() for r in (a, b)):
        return np.array([], dtype=np.int64)
    ta, tb = (pq.read_table(r.root / states) for r in (a, b))
    ta, tb = (t.replace_schema_metadata(None) for t in (ta, tb))
    if ta.schema != tb.schema:
        return np.array([], dtype=np.int64)  # another task's parameters: nothing is shared
    ids_a, ids_b = ta.column("state_id").to_numpy(), tb.column("state_id").to_numpy()
    common, ia, ib = np.intersect1d(ids_a, ids_b, return_indices=True)
    same = np.ones(len(common), dtype=bool)
    for name in ta.column_names[1:]:
        va = ta.column(name).to_numpy(zero_copy_only=False)[ia]
        vb = tb.column(name).to_numpy(zero_copy_only=False)[ib]
        same &= (va == vb) | (np.isnan(va) & np.isnan(vb) if va.dtype.kind == "f" else False)
    return common[same]


def _rate(success: np.ndarray) -> dict[str, Any]:
    n = int(success.size)
    return {"n": n, "successes": int(success.sum()), "rate": float(success.mean()) if n else None}


def compare_condition(a: Outcomes, b: Outcomes, shared: np.ndarray) -> dict[str, Any]:
    """Each run's own success rate, and on the `shared` states: both rates, McNemar's exact
    test on the pairs (`stats.mcnemar`) and the flipped states (ids, categories in each)."""
    ia = np.searchsorted(a.state_id, shared)
    ib = np.searchsorted(b.state_id, shared)
    keep = (ia < a.state_id.size) & (ib < b.state_id.size)
    keep[keep] &= (a.state_id[ia[keep]] == shared[keep]) & (b.state_id[ib[keep]] == shared[keep])
    ia, ib, ids = ia[keep], ib[keep], shared[keep]
    sa, sb = a.success[ia], b.success[ib]
    test = stats.mcnemar(sa, sb) if ids.size else None
    flipped = np.flatnonzero(sa != sb)
    return {
        "a": _rate(a.success),
        "b": _rate(b.success),
        "paired": {
            "n": int(ids.size),
            "a": _rate(sa),
            "b": _rate(sb),
            "only_a": test.only_a if test else 0,
            "only_b": test.only_b if test else 0,
            "p_value": test.p_value if test else None,
            "method": stats.MCNEMAR_METHOD,
        },
        "flipped": [
            {
                "state_id": int(ids[i]),
                "success": [bool(sa[i]), bool(sb[i])],
                "failure_category": [a.failure_category[ia[i]], b.failure_category[ib[i]]],
            }
            for i in flipped
        ],
    }


def compare_conditions(a: Run, b: Run) -> dict[str, dict[str, Any]]:
    """`compare_condition` for every condition (and variant's) both runs rolled out; a group
    only one ran is `{"only": "a"}` or `"b"`."""
    ga, gb = rollout_groups(a), rollout_groups(b)
    shared: dict[str, np.ndarray] = {}
    out: dict[str, dict[str, Any]] = {}
    for group in [*ga, *(g for g in gb if g not in ga)]:
        if group not in gb or group not in ga:
            out[group] = {"only": "a" if group in ga else "b"}
            continue
        (table_a, states), (table_b, _) = ga[group], gb[group]
        if states not in shared:
            shared[states] = shared_states(a, b, states)
        out[group] = compare_condition(
            read_outcomes(a, table_a), read_outcomes(b, table_b), shared[states]
        )
    return out


# -- main effect and verdicts ----------------------------------------------------------------


def _effect(record: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """The paired difference and verdict of an experiment's summary or a variant's record;
    None for anything else (a benchmark's summary judges no falsifier)."""
    if not record or "verdict" not in (record.get("falsifier") or record):
        return None
    paired = record.get("paired_difference") or {}
    falsifier = record.get("falsifier") or record
    return {
        "estimate": paired.get("estimate"),
        "low": paired.get("low"),
        "high": paired.get("high"),
        "verdict": falsifier.get("verdict"),
    }


def _comparison_verdict(c: Mapping[str, Any]) -> str:
    """A benchmark's comparison of two methods on a task, in words (Holm-adjusted McNemar)."""
    if not c.get("significant"):
        return "no significant difference"
    return f"{c['a'] if c['difference'] > 0 else c['b']} better"


def _benchmark_effects(summary: Mapping[str, Any] | None) -> dict[str, dict[str, Any]]:
    """Each of a benchmark's comparisons (`{task}: {a} vs {b}`): the difference in success
    and its verdict."""
    out: dict[str, dict[str, Any]] = {}
    if summary is None or "paired_difference" in summary:  # an experiment's planned comparisons
        return out
    for c in summary.get("comparisons") or []:
        verdict = _comparison_verdict(c)
        estimate = {"estimate": c.get("difference"), "low": None, "high": None}
        out[f"{c['task']}: {c['a']} vs {c['b']}"] = {**estimate, "verdict": verdict}
    return out


def compare_effects(a: Run, b: Run) -> dict[str, dict[str, Any]]:
    """The main effect (the falsifier's paired difference) and its verdict in each run, for
    the experiment (`main`) and each variant of the sensitivity study both ran, or a
    benchmark's comparisons of methods per task; `changed` when the verdicts differ."""
    out: dict[str, dict[str, Any]] = {}
    summaries = [r.json(r.layout.summary.relative_to(r.root).as_posix()) for r in (a, b)]
    pairs = {"main": (_effect(summaries[0]), _effect(summaries[1]))}
    ba, bb = (_benchmark_effects(s) for s in summaries)
    pairs |= {name: (ba.get(name), bb.get(name)) for name in [*ba, *(n for n in bb if n not in ba)]}
    studies = [
        r.json(r.layout.study_summary("sensitivity").relative_to(r.root).as_posix()) for r in (a, b)
    ]
    if all(studies):
        va, vb = (s.get("variants") or {} for s in studies)
        for name in (n for n in va if n in vb and n != NOMINAL):
            pairs[f"sensitivity/{name}"] = (_effect(va[name]), _effect(vb[name]))
    for name, (ea, eb) in pairs.items():
        if ea is None and eb is None:
            continue
        verdicts = [e and e["verdict"] for e in (ea, eb)]
        out[name] = {"a": ea, "b": eb, "changed": verdicts[0] != verdicts[1]}
    return out
