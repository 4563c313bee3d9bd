"""The teachers side by side (DESIGN.md, "Teachers"): goals with their Wilson 95 %
intervals and median time to goal on the paper's 20 test seeds and on 100 fresh test seeds
(30000..30099), read from the summaries `scripts/teachers` leaves in models/teachers/.

    python -m dribble_models.teachers models/teachers [--out models/teachers/teachers.md]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

TEACHERS = ("paper", "observable", "orbit")
SETS = (("test", "20 test seeds 10000..10019"), ("fresh", "100 fresh seeds 30000..30099"))


def wilson(goals: int, episodes: int, z: float = 1.959964) -> tuple[float, float]:
    """The Wilson score interval of a goal share (95 % by default)."""
    if episodes == 0:
        return (0.0, 1.0)
    p = goals / episodes
    centre = (p + z * z / (2 * episodes)) / (1 + z * z / episodes)
    half = z / (1 + z * z / episodes) * math.sqrt(p * (1 - p) / episodes + z * z / (4 * episodes * episodes))
    return (max(0.0, centre - half), min(1.0, centre + half))


def cell(summary: dict | None) -> tuple[str, str]:
    if summary is None:
        return ("-", "-")
    episodes = summary["episodes"]
    goals = [e for e in episodes if e["outcome"] == "goal"]
    low, high = wilson(len(goals), len(episodes))
    median = f"{statistics.median(e['duration_s'] for e in goals):.1f} s" if goals else "-"
    return (f"{len(goals)} / {len(episodes)} ({low:.2f}-{high:.2f})", median)


def table(directory: Path) -> str:
    header = "| teacher |" + "".join(f" goals, {words} (95 % interval) | median time to goal |" for _, words in SETS)
    lines = [header, "|---|" + "---|---|" * len(SETS)]
    for teacher in TEACHERS:
        cells = []
        for name, _ in SETS:
            path = directory / f"{teacher}-{name}.json"
            cells += cell(json.loads(path.read_text()) if path.is_file() else None)
        lines.append(f"| {teacher} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.teachers", description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", type=Path, help="where scripts/teachers left the summaries")
    parser.add_argument("--out", type=Path, help="also write the table here")
    args = parser.parse_args(argv)
    text = table(args.directory)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
