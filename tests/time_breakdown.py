"""`pytest --time-breakdown`: where the suite's time goes, by what the tests wait for.

`--durations` names the slowest tests; this says what they were doing: running Snakemake,
verifying, running another process, copying a workflow, or working in the test's own process.
Each call is counted once, under the outermost of these it happened in (a Snakemake run's
jobs are inside its run; a run started as a process of its own is a Snakemake run too). Each
test's time includes the fixtures it set up first. Workers (pytest-xdist) each write one line
per test to a folder that the main process reads at the end, so the table covers the whole run.
"""

from __future__ import annotations

import collections
import functools
import json
import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import pytest

FOLDER = "MJTRIAL_TIME_BREAKDOWN"  # environment variable: where the workers write
SNAKEMAKE, VERIFY, PROCESS, COPY, OWN = (
    "Snakemake runs",
    "verify",
    "other processes",
    "copying folders",
    "in the test's process",
)


class TimeBreakdown:
    """The pytest plugin: wraps what tests wait for, and writes each test's split."""

    def __init__(self) -> None:
        self.spent: collections.Counter[str] = collections.Counter()
        self.calls: collections.Counter[str] = collections.Counter()
        self.depth = 0

    def wrap(self, owner: object, name: str, category: str | Callable[..., str]) -> None:
        """`owner.name` timed under `category` (or the category it gives for the call)."""
        original = getattr(owner, name)

        @functools.wraps(original)
        def timed(*args, **kwargs):
            self.depth += 1
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                self.depth -= 1
                if self.depth == 0:
                    what = category(*args, **kwargs) if callable(category) else category
                    self.spent[what] += time.perf_counter() - start
                    self.calls[what] += 1

        setattr(owner, name, timed)

    def pytest_configure(self, config: pytest.Config) -> None:
        import forked_snakemake

        from mjtrial import verify
        from mjtrial.benchmark import verify as benchmark_verify

        if FOLDER not in os.environ:  # the main process: workers inherit the folder
            os.environ[FOLDER] = tempfile.mkdtemp(prefix="mjtrial-time-")
        self.wrap(forked_snakemake, "run", SNAKEMAKE)
        self.wrap(verify, "verify_results", VERIFY)
        self.wrap(benchmark_verify, "verify_benchmark", VERIFY)
        self.wrap(subprocess, "run", _process_category)
        self.wrap(shutil, "copytree", COPY)

    @pytest.hookimpl(wrapper=True)
    def pytest_runtest_protocol(self, item: pytest.Item, nextitem: pytest.Item | None):
        self.spent.clear()
        self.calls.clear()
        start = time.perf_counter()
        try:
            return (yield)
        finally:
            total = time.perf_counter() - start
            spent = dict(self.spent, **{OWN: total - sum(self.spent.values())})
            line = {"test": item.nodeid, "spent": spent, "calls": dict(self.calls)}
            path = Path(os.environ[FOLDER]) / f"{os.getpid()}.jsonl"
            with path.open("a", encoding="utf-8") as f:
                f.write(json.dumps(line) + "\n")

    def pytest_terminal_summary(self, terminalreporter) -> None:
        if hasattr(terminalreporter.config, "workerinput"):
            return
        folder = Path(os.environ[FOLDER])
        lines = [json.loads(s) for f in folder.glob("*.jsonl") for s in f.read_text().splitlines()]
        shutil.rmtree(folder, ignore_errors=True)
        for line in summary(lines):
            terminalreporter.write_line(line)


def _process_category(args, *rest, **kwargs) -> str:
    """A Snakemake run in a fresh process (another copy of the package) is a Snakemake run."""
    command = [args] if isinstance(args, str | os.PathLike) else list(args)
    return SNAKEMAKE if Path(command[0]).name == "snakemake" else PROCESS


def summary(lines: list[dict], files: int = 15) -> list[str]:
    """The table: seconds by category over the run, then the files that took longest."""
    spent: collections.Counter[str] = collections.Counter()
    calls: collections.Counter[str] = collections.Counter()
    by_file: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    for line in lines:
        spent.update(line["spent"])
        calls.update(line["calls"])
        by_file[line["test"].split("::")[0]].update(line["spent"])
    total = sum(spent.values())
    out = [f"time breakdown: {len(lines)} tests, {total:.0f} s summed over the workers"]
    for category in (SNAKEMAKE, VERIFY, PROCESS, COPY, OWN):
        n = calls[category]
        count = f"{n} call{'s' * (n != 1)}" if category in calls else ""
        share = spent[category] / total if total else 0.0
        out.append(f"  {spent[category]:7.0f} s {share:4.0%}  {category} {count}".rstrip())
    out.append(f"the {files} files that took longest (s: all, then by category as above):")
    slowest = sorted(by_file.items(), key=lambda item: -sum(item[1].values()))[:files]
    for name, split in slowest:
        parts = " ".join(f"{split[c]:5.0f}" for c in (SNAKEMAKE, VERIFY, PROCESS, COPY, OWN))
        out.append(f"  {sum(split.values()):6.0f}  {parts}  {name}")
    return out
