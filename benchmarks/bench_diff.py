"""Benchmark: `mjtrial diff` of two N = 20,000 runs, its time and peak memory.

Two such runs take an hour to build; their tables take seconds to write. The benchmark builds
one small run of the gantry experiment (32 states, every episode recorded), copies its results
folder twice and grows each copy's tables to N states in shards of 1,000 (the states, every
condition's table and shard tables, each stamped as the run stamped it, the seal listing them
all), the second copy with 2 % of each condition's outcomes flipped. The small run's recordings
stay (its 32 episodes, shard 0): the diff traces the flips among them and copies them into
its recording. It then runs `mjtrial diff A B --json` in a process of its own and prints its
wall time and peak resident memory.

    python benchmarks/bench_diff.py                  # N = 20,000
    python benchmarks/bench_diff.py --n 2000 --keep /tmp/bench-diff
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

from mjtrial import REPO_ROOT, provenance
from mjtrial.files.layout import Layout

RESULTS = Path("results") / "research_mode"
SHARD_SIZE = 1000
FLIPPED_SHARE = 0.02


def build_small_run(workdir: Path) -> Path:
    workdir.mkdir(parents=True, exist_ok=True)
    for name in ("Snakefile", "workflow", "config", "models", "tasks", "profiles"):
        src = REPO_ROOT / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, workdir / name)
    config_file = workdir / "config" / "config.yaml"
    config = yaml.safe_load(config_file.read_text())
    config["states"]["n"], config["rollout"]["shard_size"] = 32, 32
    config["analysis"]["n_resamples"] = 500
    config_file.write_text(yaml.safe_dump(config, sort_keys=False))
    snakemake = str(Path(sys.executable).parent / "snakemake")
    subprocess.run([snakemake, "-c2"], cwd=workdir, check=True, capture_output=True)
    return workdir / RESULTS


def _grown(table: pa.Table, n: int, rng: np.random.Generator) -> pa.Table:
    """`table`'s rows drawn again to n rows, `state_id` 0..n-1."""
    rows = rng.integers(0, table.num_rows, n)
    grown = table.take(pa.array(rows))
    return grown.set_column(0, "state_id", pa.array(np.arange(n, dtype=np.int64)))


def grow(folder: Path, n: int, *, flip: bool, seed: int) -> None:
    """Grow the run in `folder` to n states (see the module's docstring)."""
    rng = np.random.default_rng(seed)
    layout = Layout(folder)
    seal = json.loads(layout.seal.read_text())
    prefix = RESULTS.as_posix() + "/"
    outputs = {k: v for k, v in seal["outputs"].items() if "/shard-00000.parquet" not in k}

    def write(path: Path, table: pa.Table, stamp: dict) -> None:
        provenance.write_parquet(table, path, stamp)
        rel = prefix + path.relative_to(folder).as_posix()
        outputs[rel] = provenance.file_sha256(path)

    states = pq.read_table(layout.states)
    write(
        layout.states,
        _grown(states.replace_schema_metadata(None), n, rng),
        provenance.read_stamp(layout.states),
    )
    for table_path in sorted((folder / "rollouts").glob("*.parquet")):
        stamp = provenance.read_stamp(table_path)
        table = _grown(
            pq.read_table(table_path).replace_schema_metadata(None), n, np.random.default_rng(seed)
        )
        if flip:
            success = table.column("success").to_numpy(zero_copy_only=False).copy()
            flipped = rng.random(n) < FLIPPED_SHARE
            success[flipped] = ~success[flipped]
            table = table.set_column(
                table.schema.get_field_index("success"), "success", pa.array(success)
            )
        write(table_path, table, stamp)
        condition = table_path.stem
        shard_stamp = provenance.read_stamp(folder / "rollouts" / condition / "shard-00000.parquet")
        for i, first in enumerate(range(0, n, SHARD_SIZE)):
            shard = folder / "rollouts" / condition / f"shard-{i:05d}.parquet"
            write(shard, table.slice(first, SHARD_SIZE), shard_stamp)
    seal["outputs"] = dict(sorted(outputs.items()))
    layout.seal.write_text(json.dumps(seal))


# The diff in a process of its own that reports its own peak (the children's peak would be
# Snakemake's, which built the small run).
_MEASURED = (
    "import resource, sys; from mjtrial.cli import main; code = main(sys.argv[1:]); "
    "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); sys.exit(code)"
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20_000)
    parser.add_argument("--keep", type=Path, help="build in this folder and keep it")
    args = parser.parse_args()
    base = args.keep or Path(tempfile.mkdtemp(prefix="bench-diff-"))
    base.mkdir(parents=True, exist_ok=True)
    small = build_small_run(base / "small")
    for side, flip in (("a", False), ("b", True)):
        target = base / side / RESULTS
        shutil.copytree(small, target, ignore=shutil.ignore_patterns("source", "logs"))
        grow(target, args.n, flip=flip, seed=1)
    command = [sys.executable, "-c", _MEASURED, "diff", str(base / "a" / RESULTS)]
    command += [str(base / "b" / RESULTS), "--json", "--out", str(base / "out")]
    start = time.perf_counter()
    proc = subprocess.run(command, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        sys.exit(proc.stderr)
    peak_mb = int(proc.stderr.strip().splitlines()[-1]) / 1024
    diff = json.loads(proc.stdout)
    flips = sum(len(c.get("flipped", [])) for c in diff["conditions"].values())
    print(
        f"mjtrial diff of two N = {args.n} runs ({flips} flipped episodes): "
        f"{wall:.1f} s, peak RSS {peak_mb:.0f} MB"
    )
    if args.keep is None:
        shutil.rmtree(base, ignore_errors=True)


if __name__ == "__main__":
    main()
