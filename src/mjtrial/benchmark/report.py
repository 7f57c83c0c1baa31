"""The benchmark's report (markdown) from its summary: the headline rate first, both overall
rates in tables of their own, the IQM over seeds, every task's rates with their spread over
seeds, the paired differences, the budgets (an asymmetry flagged), the tuned parameters and
each policy file a method ran. A method not run on a task says so in that task's rows, and its
overall rates carry the tasks they are over."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

RATE_NAMES = {
    "task_mean": "Task mean (the mean of the per-task rates; every task weighs the same)",
    "episode_mean": "Episode mean (every episode of every task pooled; more states, more weight)",
}


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _ci(rec: Mapping[str, float]) -> str:
    return f"{_pct(rec['estimate'])} [{_pct(rec['low'])}, {_pct(rec['high'])}]"


def _spread(rec: Mapping[str, float]) -> str:
    return f"{_pct(rec['min'])} / {_pct(rec['median'])} / {_pct(rec['max'])}"


def _labelled(method: str, rec: Mapping[str, Any]) -> str:
    """A method's name, with the tasks its overall rates are over if not every task."""
    return f"{method} ({', '.join(rec['tasks'])} only)" if "tasks" in rec else method


def _overall_table(summary: Mapping[str, Any], rate: str) -> list[str]:
    seeds = [str(s) for s in summary["seeds"]]
    lines = [
        f"### {RATE_NAMES[rate]}",
        "",
        "| method | min / median / max over seeds | "
        + " | ".join(f"seed {s}" for s in seeds)
        + " |",
        "| --- | --- |" + " --- |" * len(seeds),
    ]
    for method, rec in summary["overall"].items():
        cells = [_ci(rec[rate]["per_seed"][s]) for s in seeds]
        lines.append(
            f"| {_labelled(method, rec)} | {_spread(rec[rate]['spread_over_seeds'])} | "
            + " | ".join(cells)
            + " |"
        )
    return lines + [""]


def benchmark_report(
    summary: Mapping[str, Any], closest_calls: Sequence[Mapping[str, Any]] = ()
) -> str:
    """The report's markdown; `closest_calls`: the rows of `replay/closest_calls.parquet`."""
    seeds, tasks, methods = summary["seeds"], summary["tasks"], summary["methods"]
    confidence = summary["intervals"]["confidence"]
    level = f"{100 * confidence:g} %"
    headline = summary["headline"]
    out = [
        f"# Benchmark: {summary['question']}",
        "",
        f"**{summary['result'].capitalize()}**: {len(seeds)} training seeds "
        f"({', '.join(map(str, seeds))}), {len(tasks)} tasks ({', '.join(tasks)}), "
        f"{len(methods)} methods.",
        "",
        "## Methods",
        "",
    ]
    out += [f"- **{m}**: {summary['method_descriptions'][m]}" for m in methods]
    out += ["", f"## Headline: {RATE_NAMES[headline].split(' (')[0].lower()}", ""]
    not_run = summary.get("not_run", {})
    if not_run:
        skipped = "; ".join(f"{m} not on {', '.join(t)}" for m, t in not_run.items())
        out += [
            f"Each method's rates are over the tasks it ran ({skipped}): a method labelled with "
            "its tasks is not compared with the others over every task; compare them per task.",
            "",
        ]
    for method, rec in summary["overall"].items():
        out.append(
            f"- {_labelled(method, rec)}: {_spread(rec[headline]['spread_over_seeds'])} (min / "
            f"median / max over seeds); IQM over seeds and tasks {_ci(rec['iqm'])}"
        )
    out += ["", "## Solvability", ""]
    for task, rec in summary["solvability"].items():
        reference = ", ".join(f"{k} {v:g}" for k, v in rec["reference"].items()) or "its defaults"
        out.append(
            f"- **{task}**: {rec['solved']} of {rec['n']} probe states ({rec['probe']} of the "
            f"state ranges) solved by the reference controller ({reference})."
        )
        for r in rec["unsolved"]:
            where = ", ".join(f"{k} {v:.4g}" for k, v in r.items() if k != "failure_category")
            out.append(f"  - unsolvable: {where} ({r['failure_category']})")
    out += ["", "## Overall success rates", ""]
    out += [
        "Two different overall rates; each is in a table of its own and they are never mixed. "
        f"Intervals: {level}, per seed ({summary['intervals']['episode_mean']}; "
        f"{summary['intervals']['task_mean']}).",
        "",
    ]
    for rate in (headline, *(r for r in RATE_NAMES if r != headline)):
        out += _overall_table(summary, rate)
    out += [
        "## Interquartile mean over training seeds",
        "",
        f"The IQM of every (seed, task) success rate, with a {level} "
        f"{summary['intervals']['iqm']} ({summary['intervals']['n_resamples']} resamples); "
        "`analysis/summary.json` holds each method's performance profile with its band, drawn "
        "below: the fraction of (seed, task) success rates above each threshold.",
        "",
        "![Performance profiles](figures/performance_profile.png)",
        "",
        "| method | IQM |",
        "| --- | --- |",
    ]
    out += [f"| {_labelled(m, rec)} | {_ci(rec['iqm'])} |" for m, rec in summary["overall"].items()]
    out += [
        "",
        "## Per task",
        "",
        "| task | method | pooled over seeds (Wilson) | min / median / max over seeds |",
        "| --- | --- | --- | --- |",
    ]
    for task in tasks:
        for method in methods:
            if method not in summary["per_task"][task]:
                out.append(f"| {task} | {method} | not run on this task | |")
                continue
            rec = summary["per_task"][task][method]
            pooled = rec["pooled_over_seeds"]
            out.append(
                f"| {task} | {method} | {_pct(pooled['rate'])} [{_pct(pooled['low'])}, "
                f"{_pct(pooled['high'])}] ({pooled['successes']}/{pooled['n']}) | "
                f"{_spread(rec['spread_over_seeds'])} |"
            )
    out += ["", "## Paired differences", "", f"{summary['comparisons_method']}.", ""]
    out += [
        "| task | methods | rates | difference | only first / only second | p | p (Holm) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for c in summary["comparisons"]:
        out.append(
            f"| {c['task']} | {c['a']} vs {c['b']} | {_pct(c['rate_a'])} vs {_pct(c['rate_b'])} | "
            f"{100 * c['difference']:+.1f} points | {c['only_a']} / {c['only_b']} | "
            f"{c['p_value']:.3g} | {c['p_holm']:.3g}{' *' if c['significant'] else ''} |"
        )
    out += [
        "",
        "## Tuning budgets",
        "",
        "| method | budget (episodes per task and seed) | used |",
        "| --- | --- | --- |",
    ]
    for m, rec in summary["budgets"].items():
        used = [u for per_task in rec["used"].values() for u in per_task.values()]
        out.append(f"| {m} | {rec['episodes']} | {min(used)}..{max(used)} |")
    if summary["unequal_budgets"]:
        out += ["", f"**The budgets differ.** {summary['unequal_budgets']}"]
    out += [
        "",
        "## Tuned parameters",
        "",
        "| task | method | seed | parameters |",
        "| --- | --- | --- | --- |",
    ]
    for key, params in summary["tuned_parameters"].items():
        task, method, seed = key.split(":")
        shown = ", ".join(f"{k} {v:.4g}" for k, v in params.items())
        out.append(f"| {task} | {method} | {seed} | {shown} |")
    out += _policy_files(summary.get("policy_files", {}))
    out += _closest_calls(closest_calls)
    return "\n".join(out) + "\n"


def _policy_files(files: Mapping[str, Mapping[str, str]]) -> list[str]:
    """The section naming each policy file a run evaluated, one per training seed."""
    if not files:
        return []
    out = [
        "",
        "## Policy files",
        "",
        "Each training seed of a method that runs trained policies is one file, evaluated as its "
        "contract says (sha256 of the graph and of the contract).",
        "",
        "| task | method | seed | file | sha256 | contract | contract sha256 |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for key, rec in files.items():
        task, method, seed = key.split(":")
        out.append(
            f"| {task} | {method} | {seed} | {rec['path']} | {rec['sha256'][:12]} "
            f"| {rec['contract']} | {rec['contract_sha256'][:12]} |"
        )
    return out


def _closest_calls(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The section listing the episodes of `replay/closest_calls.rrd`, to be watched."""
    out = [
        "",
        "## Closest calls",
        "",
        "Watch these before trusting a rate (`rerun replay/closest_calls.rrd`): per task, the "
        "successes that passed by the smallest margin and the episodes of largest margin, the "
        "task's highest scores, where a success test passed the wrong way shows. Each was "
        "re-simulated and reproduced its evaluation row; a method that tunes nothing and runs "
        "no policy file of its own per seed ran the same episodes under every seed, so its "
        "first seed stands for all.",
        "",
    ]
    if not rows:
        return out + ["No task declares a margin, or no episode has one."]
    out += [
        "| task | kind | method | seed | state | success | margin |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        out.append(
            f"| {r['task']} | {r['kind']} {r['rank']} | {r['method']} | {r['seed']} "
            f"| {r['state_id']} | {'yes' if r['success'] else 'no'} "
            f"| {r['margin']:.4g} ({r['margin_measure']}) |"
        )
    return out
