"""`mjtrial plan`: a sample size before a run, or a registered design's power from its pilot;
split from the rest of `mjtrial.cli` by size."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mjtrial import stats
from mjtrial.files.layout import Layout


def _registered_plan(args: argparse.Namespace) -> int:
    """`mjtrial plan RESULTS_DIR`: the registered design's power, from its pilot now."""
    from mjtrial.design import registration  # the registered design (no MuJoCo): planning only
    from mjtrial.stats.power import plan_lines

    layout = Layout(Path(args.results_dir))
    try:
        data = registration.read(layout.registration)
        if data is None:
            print(
                f"mjtrial plan: {layout.registration}: nothing registered (the first run, or "
                "`mjtrial register`, registers the design)",
                file=sys.stderr,
            )
            return 2
        design = data["current"]["design"]["sections"]
        plan = registration.registered_plan(
            design, layout=layout, discordant=args.discordant, target=args.effect
        )
    except ValueError as err:
        print(f"mjtrial plan: {err}", file=sys.stderr)
        return 2
    print(f"power of the design registered on {data['current']['registered_utc']}:")
    print("\n".join(plan_lines(plan)))
    if plan != data["current"]["plan"]:
        # after results, a plan is post hoc: registering it would record it as the design's
        rollouts = layout.rollouts_dir()
        after = rollouts.is_dir() and any(rollouts.rglob("*.parquet"))
        print(
            f"(the registration's own plan used: {data['current']['plan']['source']}; "
            + (
                f"results exist ({rollouts}), so this plan comes after them: report it as a "
                "post-hoc power analysis beside the registered plan, and do not register it)"
                if after
                else "no results yet: `mjtrial register --again --reason TEXT` records this one)"
            )
        )
    return 0


def _plan(args: argparse.Namespace) -> int:
    if args.results_dir is not None:
        return _registered_plan(args)
    if args.halfwidth is None and args.effect is None:
        print("mjtrial plan: give --halfwidth, or --effect with --discordant", file=sys.stderr)
        return 2
    try:
        if args.halfwidth is not None:
            worst = stats.episodes_for_halfwidth(args.halfwidth, 0.5, args.confidence)
            print(
                f"episodes for a {args.confidence:g} interval of half-width {args.halfwidth:g}: "
                f"{worst} (worst case, p = 0.5)"
            )
            if args.p is not None:
                at_p = stats.episodes_for_halfwidth(args.halfwidth, args.p, args.confidence)
                print(f"  at p = {args.p:g}: {at_p}")
        if args.effect is not None:
            if args.discordant is None:
                print("mjtrial plan: --effect needs --discordant", file=sys.stderr)
                return 2
            pairs = stats.mcnemar_pairs_needed(
                args.effect, args.discordant, args.power, args.confidence
            )
            print(
                f"pairs to detect a paired difference of {args.effect:g} with discordant "
                f"proportion {args.discordant:g} (McNemar, power {args.power:g}, "
                f"confidence {args.confidence:g}): {pairs}"
            )
    except ValueError as err:
        print(f"mjtrial plan: {err}", file=sys.stderr)
        return 2
    return 0
