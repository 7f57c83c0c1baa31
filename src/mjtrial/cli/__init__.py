"""The `mjtrial` command: read any output's stamp, plan a sample size."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from mjtrial import foreign_package, provenance
from mjtrial.cli.plan import _plan
from mjtrial.cli.scaffold import ScaffoldError, new_task
from mjtrial.files.layout import CONFIG_FILE, NOMINAL, RESULTS_DIR, Layout

PROFILE_NAME = "Provenance Run Crate 0.5 on RO-Crate 1.1"


def _provenance(args: argparse.Namespace) -> int:
    try:
        stamp = provenance.read_stamp(args.file)
    except (OSError, ValueError) as err:
        print(f"mjtrial provenance: {err}", file=sys.stderr)
        return 1
    print(json.dumps(stamp, indent=2))
    return 0


def _register(args: argparse.Namespace) -> int:
    # Imported here (mujoco, jsonschema through the config check): `mjtrial plan` need not.
    from mjtrial.config import ConfigError
    from mjtrial.design import registration
    from mjtrial.verify import load_checked_config

    repo_root = Path.cwd()
    config_path = Path(args.config) if args.config else repo_root / CONFIG_FILE
    try:
        config = load_checked_config(config_path, repo_root=repo_root)
        layout = Layout.of(config["experiment"], base=repo_root / RESULTS_DIR)
        if args.again and not args.reason:
            raise ValueError("--again needs --reason TEXT: the record says why it changed")
        data = registration.register(
            config, layout=layout, repo_root=repo_root, again=args.again, reason=args.reason
        )
    except (ConfigError, OSError, ValueError) as err:
        print(f"mjtrial register: {err}", file=sys.stderr)
        return 2
    current = data["current"]
    print(
        f"registered {layout.registration} on {current['registered_utc']} (design sha256 "
        f"{current['design_sha256'][:12]}; {len(data['earlier'])} earlier kept)"
    )
    seen = current.get("results_when_registered") or {}
    if seen.get("existed"):
        print(
            f"results existed ({seen['files']} file(s) in the folder, {seen['records']} of "
            "Snakemake's records): the report and the manifest say it was registered after "
            "results existed, for as long as it is the record"
        )
    return 0


def _replay(args: argparse.Namespace) -> int:
    # Imported here (mujoco, rerun-sdk): a second or so that the other commands need not pay.
    from mjtrial.config import ConfigError
    from mjtrial.replay import ReplayMismatch, open_viewer, replay_episode

    results_dir = Path(args.results_dir) if args.results_dir else None
    config_path = Path(args.config) if args.config else None
    if results_dir is not None and config_path is None:  # the config file the run recorded
        recorded = _recorded_config_file(results_dir, default=None)
        if recorded is None:
            manifest = results_dir / "manifest.json"
            why = (
                "no config file recorded (rerun.config_file)"
                if manifest.is_file()
                else "not written yet (a run writes it last: it is going on, or stopped)"
            )
            print(
                f"mjtrial replay: {manifest}: {why}; give the experiment's --config",
                file=sys.stderr,
            )
            return 2
        config_path = Path(recorded)
    try:
        result = replay_episode(
            condition=args.condition,
            state_id=args.state,
            variant=args.variant,
            results_dir=results_dir,
            output=Path(args.output) if args.output else None,
            config_path=config_path,
            force=args.force,
        )
    except (ConfigError, KeyError, OSError, ValueError, ReplayMismatch) as err:
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"mjtrial replay: {message}", file=sys.stderr)
        return 1
    print(f"{result.describe()}, as recorded -> {result.recording}")
    if not args.no_viewer and open_viewer(result.recording) is None:
        print("mjtrial replay: no `rerun` viewer found; open the file yourself", file=sys.stderr)
    return 0


def _view(args: argparse.Namespace) -> int:
    # Imported here (rerun-sdk): a second or so that the other commands need not pay.
    from mjtrial.recording import write_whole_episode
    from mjtrial.replay import open_viewer

    if (args.condition is None) != (args.state is None):
        print("mjtrial view: give both --condition and --state, or neither", file=sys.stderr)
        return 2
    output = Path(args.output) if args.output else None
    if output is not None and output.exists() and not args.force:
        print(
            f"mjtrial view: --output {output}: exists (pass --force to overwrite it)",
            file=sys.stderr,
        )
        return 2
    if output is None:  # a file of its own in a fresh folder, which the viewer then reads
        output = Path(tempfile.mkdtemp(prefix="mjtrial-view-")) / Path(args.file).name
    try:
        recording_id = write_whole_episode(
            args.file, output, condition=args.condition, state_id=args.state
        )
    except (KeyError, OSError, ValueError) as err:
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"mjtrial view: {message}", file=sys.stderr)
        return 1
    print(f"{recording_id}, with its meshes -> {output}")
    if not args.no_viewer and open_viewer(output) is None:
        print("mjtrial view: no `rerun` viewer found; open the file yourself", file=sys.stderr)
    return 0


def _count(text: str) -> int:
    """A count argument: a whole number, 0 or more."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return value


def _resimulate_count(text: str) -> int:
    """`--resimulate`: a count, or `all` (every episode of every shard)."""
    from mjtrial.verify.coverage import RESIMULATE_ALL  # no MuJoCo: a constant

    return RESIMULATE_ALL if text == "all" else _count(text)


def _recorded_config_file(results_dir: Path, default: str | None = CONFIG_FILE) -> str | None:
    """The run's config file as its manifest records it (`default` if it does not)."""
    try:
        manifest = json.loads(provenance.read_output_text(results_dir / "manifest.json"))
        recorded = manifest["rerun"]["config_file"]
    except (OSError, ValueError, KeyError, TypeError):
        return default
    return recorded if isinstance(recorded, str) else default


def _crate_config_file(results_dir: Path) -> str | None:
    """The config file a benchmark's crate records (a benchmark has no manifest), or None."""
    # Imported here (the crate package, half a second): `mjtrial plan` need not pay it.
    from mjtrial.crate.stamp import read_crate_stamp

    try:
        recorded = (read_crate_stamp(Layout(results_dir).crate) or {})["config_slice"]["rerun"]
        recorded = recorded["config_file"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return recorded if isinstance(recorded, str) else None


def _verify(args: argparse.Namespace) -> int:
    # Imported here (mujoco, rerun-sdk, jsonschema): `mjtrial plan` need not pay for them.
    from mjtrial.config import ConfigError
    from mjtrial.config.read import read_config_file
    from mjtrial.verify import DEFAULT_RESIMULATE, load_checked_config, verify_results
    from mjtrial.verify.folder import copied_from, looks_like_benchmark

    repo_root = Path(args.repo_root) if args.repo_root else Path.cwd()
    config_path = Path(args.config) if args.config else repo_root / CONFIG_FILE
    results_dir = Path(args.results_dir) if args.results_dir else None
    recorded = None  # the config file the run recorded (a manifest's, a benchmark's crate's)
    if results_dir is not None:
        recorded = _recorded_config_file(results_dir, None) or _crate_config_file(results_dir)
    if not args.config and recorded:
        config_path = repo_root / recorded
    foreign = foreign_package(repo_root)
    if foreign:
        print(f"mjtrial verify: {foreign}", file=sys.stderr)
        return 2
    resimulate = args.resimulate  # None: every episode if that fits verify's time budget
    if args.strict and resimulate == 0:
        print(
            "mjtrial verify: --strict with --resimulate 0: a strict check re-simulates "
            "episodes; give --resimulate K > 0 (or `all`), or leave it out",
            file=sys.stderr,
        )
        return 2
    try:
        if results_dir is not None:
            # an experiment's copy is verified as what it is (`verify_results`); a benchmark's
            # is named
            origin = copied_from(results_dir, repo_root=repo_root)
            if origin and (looks_like_benchmark(results_dir) or _is_benchmark_file(config_path)):
                print(f"mjtrial verify: {origin}", file=sys.stderr)
                return 2
            if not args.config and not recorded and looks_like_benchmark(results_dir):
                print(
                    f"mjtrial verify: {results_dir} is a benchmark's folder that records no "
                    "config file (no ro-crate-metadata.json): give it, --config "
                    "config/<benchmark>.yaml",
                    file=sys.stderr,
                )
                return 2
        if _is_benchmark_file(config_path):
            benchmark_sample = DEFAULT_RESIMULATE if resimulate is None else resimulate
            return _verify_benchmark(
                config_path, repo_root, results_dir, benchmark_sample, args.seed
            )
        if results_dir is None:
            # the experiment's name is all this needs: `verify_results` checks the config (a
            # second check here cost a second second of the task's nominal episodes)
            experiment = read_config_file(config_path).get("experiment")
            if not isinstance(experiment, str):
                experiment = load_checked_config(config_path, repo_root=repo_root)["experiment"]
            results_dir = Layout.of(experiment, base=repo_root / RESULTS_DIR).root
        report = verify_results(
            results_dir,
            config_path=config_path,
            repo_root=repo_root,
            resimulate=resimulate,
            seed=args.seed,
        )
    except (ConfigError, OSError, ValueError) as err:
        print(f"mjtrial verify: {err}", file=sys.stderr)
        return 2
    print(report.format())
    if args.strict and report.ok and not report.complete:
        doubts = [*report.warnings, *report.unchecked]
        print(
            f"mjtrial verify --strict: not verified: {len(doubts)} warnings or checks not done "
            f"(first: {doubts[0]})",
            file=sys.stderr,
        )
        return 1
    return report.exit_code


def _is_benchmark_file(config_path: Path) -> bool:
    # Imported here (jsonschema, mujoco through the config module): `mjtrial plan` need not
    # pay for them.
    from mjtrial.benchmark import is_benchmark
    from mjtrial.config.read import read_config_file

    return config_path.is_file() and is_benchmark(read_config_file(config_path))


def _verify_benchmark(
    config_path: Path,
    repo_root: Path,
    results_dir: Path | None,
    resimulate: int,
    seed: int | None = None,
) -> int:
    """`mjtrial verify --config config/benchmark.yaml` (or the benchmark's folder, whose crate
    records its config file): the benchmark's split, files and derived numbers."""
    # Imported here (mujoco, cma, scipy): `mjtrial plan` need not pay for them.
    from mjtrial.benchmark.config import check_benchmark_config
    from mjtrial.benchmark.verify import verify_benchmark
    from mjtrial.config.read import read_config_file
    from mjtrial.files.layout import BenchmarkLayout

    config = read_config_file(config_path)
    tasks = check_benchmark_config(config, source=str(config_path), repo_root=repo_root)
    root = BenchmarkLayout.of(config["experiment"]).root
    if results_dir is not None and provenance.path_in_repo(results_dir, repo_root) != (
        root.as_posix()
    ):
        print(
            f"mjtrial verify: {results_dir} is not the folder of the benchmark {config_path} "
            f"describes ({root.as_posix()})",
            file=sys.stderr,
        )
        return 2
    verdict = verify_benchmark(
        config, tasks, repo_root=repo_root, resimulate=resimulate, sample_seed=seed
    )
    print(verdict.format())
    return verdict.exit_code


def _crate(args: argparse.Namespace) -> int:
    # Imported here: the crate reads stamps (rerun-sdk) and uses the rocrate library, which
    # `mjtrial plan` need not load.
    from mjtrial.config.read import ConfigError, read_config_file
    from mjtrial.crate.archive import (
        ArchiveError,
        check_crate,
        folder_members,
        left_out_summary,
        write_archive,
    )

    repo_root = Path(args.repo_root) if args.repo_root else Path.cwd()
    foreign = foreign_package(repo_root)
    if foreign:
        print(f"mjtrial crate: {foreign}", file=sys.stderr)
        return 2
    try:
        if args.results_dir:
            results_dir = Path(args.results_dir)
        else:
            config_path = Path(args.config) if args.config else repo_root / CONFIG_FILE
            experiment = read_config_file(config_path)["experiment"]
            results_dir = Layout.of(experiment, base=repo_root / RESULTS_DIR).root
        layout = Layout(results_dir)
        differs = check_crate(layout, repo_root=repo_root)
        if differs:
            for path, why in differs.items():
                print(
                    f"mjtrial crate: {path} and the folder differ: {why}; `mjtrial verify` "
                    "says which changed",
                    file=sys.stderr,
                )
            return 1
        members = folder_members(layout, repo_root=repo_root)
        described = len(members.packed)
        print(f"crate ok: {layout.crate} describes the run's {described} files as they are")
        others = left_out_summary(layout, members.left_out)
        if args.zip:
            archive = write_archive(results_dir, Path(args.zip), repo_root=repo_root)
            print(f"wrote {archive.path}: {archive.files} files, {archive.bytes / 1e6:.1f} MB")
            if others:
                print(f"left out of it: {others}; it holds what the crate describes")
        elif others:
            print(f"not the run's (--zip leaves them out): {others}")
        if args.validate:
            from mjtrial.crate.validation import validate  # the validator: a test dependency

            with tempfile.TemporaryDirectory(prefix="mjtrial-validator-") as cache:
                findings = validate(layout.root, cache_path=Path(cache) / "http_cache")
            for finding in findings:
                print(finding.line())
            print(f"validator: {len(findings)} REQUIRED issues ({PROFILE_NAME}, offline)")
            if findings:
                return 1
    except ImportError as err:
        print(
            f"mjtrial crate: --validate needs rocrate-validator ({err}): pip install -e '.[test]'",
            file=sys.stderr,
        )
        return 2
    except (ArchiveError, ConfigError, OSError, ValueError, KeyError) as err:
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"mjtrial crate: {message}", file=sys.stderr)
        return 1
    return 0


def _new_task(args: argparse.Namespace) -> int:
    root = Path(args.repo_root or ".")
    try:
        written = new_task(args.name, repo_root=root)
    except ScaffoldError as err:
        print(f"mjtrial {err}", file=sys.stderr)
        return 2
    for path in written:
        print(f"wrote {path}")
    config = written[-1].relative_to(root).as_posix()
    print(
        f"run it:    snakemake -c2 --configfile {config}\n"
        f"studies:   snakemake -c2 studies --configfile {config}\n"
        f"check it:  mjtrial verify results/{args.name}"
    )
    return 0


def _policy_check(args: argparse.Namespace) -> int:
    # imported here: onnxruntime's import would slow every other command
    from mjtrial.policy_files.check import check_policy_file, parse_settings, policy_check_task
    from mjtrial.task import TaskError

    try:
        condition = parse_settings(args.set or [])
    except ValueError as err:
        print(f"mjtrial policy check: {err}", file=sys.stderr)
        return 2
    try:
        task = policy_check_task(args.task, condition)
        found = check_policy_file(args.file, task, condition=condition)
    except TaskError as err:  # PolicyFileError included: one line naming the file
        print(f"mjtrial policy check: {err}", file=sys.stderr)
        return 2
    print("\n".join(found.lines()))
    return 0 if found.invariant else 1


def _diff(args: argparse.Namespace) -> int:
    # Imported here: the diff reads recordings (rerun-sdk), which `mjtrial plan` need not pay.
    from mjtrial.diff import RunError, diff_runs, failures, render

    given = {"tolerance": args.tolerance, "max_episodes": args.max_episodes, "level": args.level}
    try:
        diff = diff_runs(
            args.a,
            args.b,
            recording=Path(args.out) / "replay" / "diff.rrd",
            **{k: v for k, v in given.items() if v is not None},
        )
    except (RunError, ValueError, OSError) as err:
        print(f"mjtrial diff: {err}", file=sys.stderr)
        return 2
    failed = failures(diff, args.fail_on) if args.fail_on else []
    if args.json:
        print(json.dumps({**diff, "fail_on": args.fail_on, "failed": failed}, indent=1))
    else:
        print(render(diff))
    for line in failed:
        print(f"mjtrial diff --fail-on {args.fail_on}: {line}", file=sys.stderr)
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="mjtrial", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("provenance", help="print the provenance stamp of an output as JSON")
    p.add_argument(
        "file",
        help="any file under results: an output (.parquet, .json, .md, .png, .svg, .rrd, a "
        "folder of recordings, the crate), a log, or a file inside a folder output",
    )
    p.set_defaults(run=_provenance)
    p = sub.add_parser(
        "plan",
        help="episodes needed for an interval width or a paired effect; with a results "
        "folder, the registered design's power (exact McNemar, from its pilot)",
    )
    p.add_argument(
        "results_dir",
        nargs="?",
        help="a results folder with a registration: its minimum detectable paired difference "
        "at 80%% power (--effect: the pairs for that difference; --discordant: instead of the "
        "pilot's)",
    )
    p.add_argument("--halfwidth", type=float, help="half-width of a success rate's interval")
    p.add_argument("--p", type=float, help="expected success rate (default: worst case 0.5)")
    p.add_argument("--effect", type=float, help="paired difference to detect")
    p.add_argument("--discordant", type=float, help="expected proportion of discordant pairs")
    p.add_argument("--power", type=float, default=0.8)
    p.add_argument("--confidence", type=float, default=0.95)
    p.set_defaults(run=_plan)
    p = sub.add_parser(
        "register",
        help="freeze the design record in results/<experiment>/registration.json (the first "
        "run does it too); --again registers anew, keeping the earlier one in the record",
    )
    p.add_argument("--config", help="config file (default: config/config.yaml)")
    p.add_argument("--again", action="store_true", help="replace the current registration")
    p.add_argument("--reason", help="why the design is registered again (with --again)")
    p.set_defaults(run=_register)
    p = sub.add_parser(
        "replay",
        help="re-simulate one episode, write its .rrd at full rate, check it matches the record",
    )
    p.add_argument(
        "results_dir",
        nargs="?",
        help="results folder; its manifest names the config (default: results/<experiment>)",
    )
    p.add_argument("--condition", required=True)
    p.add_argument("--state", type=int, required=True, help="state_id")
    p.add_argument(
        "--variant",
        default=NOMINAL,
        help=f"a simulator variant of the config's variants (default: {NOMINAL}, the model as "
        "committed)",
    )
    p.add_argument(
        "--output",
        help="the .rrd to write (default: replays/<exp>/<condition>_state<id>.rrd, outside the "
        "sealed results folder)",
    )
    p.add_argument(
        "--config",
        help="config file (default: the one the results folder's manifest records, else "
        "config/config.yaml)",
    )
    p.add_argument("--no-viewer", action="store_true", help="do not open the Rerun viewer")
    p.add_argument(
        "--force",
        action="store_true",
        help="overwrite an existing --output outside the results folder that replay did not write",
    )
    p.set_defaults(run=_replay)
    p = sub.add_parser(
        "view",
        help="open one recorded episode with its meshes (an episode's file, or one of a "
        "failures.rrd), which the viewer does not find alone",
    )
    p.add_argument(
        "file",
        help="an episode's .rrd (its folder's meshes.rrd beside it), or a "
        "file of several with --condition and --state",
    )
    p.add_argument("--condition")
    p.add_argument("--state", type=int, help="state_id")
    p.add_argument("--output", help="the .rrd to write (default: in a new temporary folder)")
    p.add_argument("--no-viewer", action="store_true", help="do not open the Rerun viewer")
    p.add_argument("--force", action="store_true", help="overwrite an existing --output")
    p.set_defaults(run=_view)
    p = sub.add_parser(
        "verify",
        help="check every output's stamp against the files, config, model and code of now",
    )
    p.add_argument("results_dir", nargs="?", help="results folder (default: results/<experiment>)")
    p.add_argument(
        "--config",
        help="config file (default: the one the results folder's manifest records, or a "
        "benchmark's crate; without either, or without results_dir, config/config.yaml)",
    )
    p.add_argument(
        "--repo-root",
        help="folder the pipeline ran in; stamps record paths relative to it (default: .)",
    )
    p.add_argument(
        "--resimulate",
        type=_resimulate_count,
        metavar="K",
        help="episodes re-simulated per shard and compared with its table, or `all` (default: "
        "every one when that fits mjtrial.verify.coverage.RESIMULATE_BUDGET_S of CPU, else "
        "mjtrial.verify.DEFAULT_RESIMULATE per shard, a benchmark's always; 0: none)",
    )
    p.add_argument(
        "--seed",
        type=_count,
        metavar="N",
        help="draw the re-simulated episodes with this seed, to repeat a check (default: a "
        "fresh seed, printed)",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="also fail (exit 1) on a warning or a check that could not run, such as a "
        "MuJoCo-version variant whose environment is not built: for a CI gate",
    )
    p.set_defaults(run=_verify)
    p = sub.add_parser(
        "crate",
        help="check a results folder's RO-Crate (ro-crate-metadata.json) against the folder; "
        "--zip packs the run's files (what the crate lists) and its sources into one archive",
    )
    p.add_argument("results_dir", nargs="?", help="results folder (default: results/<experiment>)")
    p.add_argument("--zip", metavar="OUT.zip", help="write the archive here")
    p.add_argument("--config", help="config file of the experiment (default: config/config.yaml)")
    p.add_argument(
        "--repo-root",
        help="folder the pipeline ran in; the seals record paths relative to it (default: .)",
    )
    p.add_argument(
        "--validate",
        action="store_true",
        help=f"also run rocrate-validator offline ({PROFILE_NAME}, REQUIRED); needs the test extra",
    )
    p.set_defaults(run=_crate)
    p = sub.add_parser(
        "new-task",
        help="write tasks/NAME/ (a model and task.py to edit) and config/NAME.yaml, which run "
        "as generated",
    )
    p.add_argument("name", help="the task's name: lower-case letters, digits and _")
    p.add_argument("--repo-root", help="the repository to write into (default: .)")
    p.set_defaults(run=_new_task)
    p = sub.add_parser("policy", help="policy files (an ONNX graph with its contract)")
    policy = p.add_subparsers(dest="policy_command", required=True)
    p = policy.add_parser(
        "check",
        help="a policy file against a task: its contract against the task and the graph, a "
        "nominal episode, batch invariance on a few states, the time per call",
    )
    p.add_argument("file", help="the .onnx file (its contract: <file>.yaml or policy.yaml)")
    p.add_argument(
        "--task",
        required=True,
        help="the task: a task.py path, an installed task's name, or a name under tasks/ "
        "(cartpole_latency: tasks/cartpole_latency/task.py)",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help="a protocol parameter of the condition (default: the task's defaults)",
    )
    p.set_defaults(run=_policy_check)

    p = sub.add_parser(
        "diff",
        help="what differs between two runs (results folders or zips): how they were made, "
        "what they found, the flipped episodes; --fail-on makes it a regression gate",
    )
    p.add_argument("a", help="a results folder, or an archive of `mjtrial crate --zip`")
    p.add_argument("b", help="the run to compare it with, the same way")
    p.add_argument("--json", action="store_true", help="print the diff as JSON")
    p.add_argument(
        "--fail-on",
        choices=["any", "changed", "verdict"],
        help="exit 1 when outputs differ (any), when a condition's success changed beyond "
        "noise (changed: McNemar exact p below --level), or when a verdict changed",
    )
    p.add_argument(
        "--level", type=float, help="McNemar's level (default: mjtrial.diff.DEFAULT_LEVEL)"
    )
    p.add_argument(
        "--tolerance",
        type=float,
        help="trajectories part where a logged value differs by more than this (default: "
        "mjtrial.diff.DEFAULT_TOLERANCE)",
    )
    p.add_argument(
        "--max-episodes",
        type=_count,
        metavar="K",
        help="flipped episodes traced and copied into the recording (default: as many as fit "
        "mjtrial.diff.flips.DEFAULT_RECORDING_BYTES of recordings)",
    )
    p.add_argument(
        "--out",
        default="diff",
        help="folder for replay/diff.rrd, both runs' recordings of the flipped episodes "
        "(default: ./diff; never inside a sealed results folder)",
    )
    p.set_defaults(run=_diff)
    args = parser.parse_args(argv)
    return args.run(args)

