"""Summaries of one run's pieces on disjoint seeds into the run's one summary.

    python -m dribble_models.summary_join SUMMARY.json PIECE.json [PIECE.json ...]

`scripts/conditions --seeds fresh` plays its hundred seeds as the first 20 (the `fresh20` set's
own summary) and four more pieces of 20, each summary kept as soon as its episodes end, so a
machine lost in the middle costs at most one piece. The pieces must be one run's: the same
engine, conditions and camera samples (`RUN_IDENTITY`), no seed in two of them;
else nothing is written. An episode is a function of its seed, its condition, the policy and
the engine, so pieces played on different days are one run.
"""

from __future__ import annotations

import argparse
import json
import sys
from functools import reduce
from pathlib import Path

#: What two summaries must share for their episodes to be one run's.
RUN_IDENTITY = ("engine", "conditions", "camera_samples")


def joined(first: dict, rest: dict) -> dict:
    """One summary of the episodes of `first` and `rest`, by seed: runs of the same engine,
    conditions and camera samples on seeds that do not overlap (else a ValueError)."""
    for key in RUN_IDENTITY:
        if first.get(key) != rest.get(key):
            raise ValueError(f"the two runs differ in {key}: {first.get(key)!r} and {rest.get(key)!r}")
    shared = sorted({e["seed"] for e in first["episodes"]} & {e["seed"] for e in rest["episodes"]})
    if shared:
        raise ValueError(f"both runs hold the seeds {shared[:5]}")
    summary = dict(rest)
    summary["episodes"] = sorted(first["episodes"] + rest["episodes"], key=lambda e: e["seed"])
    return summary


def join(pieces: list[dict]) -> dict:
    """One summary of every piece's episodes, by seed (a ValueError where two pieces are not
    one run's, or share a seed)."""
    if not pieces:
        raise ValueError("no pieces to join")
    return reduce(lambda summary, piece: joined(piece, summary), pieces[1:], pieces[0])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.summary_join", description=__doc__.split("\n\n")[0])
    parser.add_argument("summary", type=Path, help="where to write the joined summary (JSON)")
    parser.add_argument("pieces", type=Path, nargs="+", help="the pieces' summaries (`eval_summary`'s files)")
    args = parser.parse_args(argv)
    try:
        pieces = [json.loads(path.read_text()) for path in args.pieces]
        summary = join(pieces)
    except (OSError, ValueError, KeyError, TypeError) as error:
        print(f"error: the pieces {', '.join(map(str, args.pieces))} are not one run: {error}", file=sys.stderr)
        return 2
    args.summary.write_text(json.dumps(summary, indent=1) + "\n")
    seeds = [e["seed"] for e in summary["episodes"]]
    goals = sum(e["outcome"] == "goal" for e in summary["episodes"])
    print(f"goals: {goals}/{len(seeds)} (seeds {min(seeds)}..{max(seeds) + 1}, {len(args.pieces)} pieces)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
