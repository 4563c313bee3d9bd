"""How many demonstration rows a teacher's perception rule changes: the same states labelled by
two teachers, row by row.

    dribble record --driver POLICY --label-with teacher --teacher observable --episodes 60..70 --out A
    dribble record --driver POLICY --label-with teacher --teacher detector --episodes 60..70 --out B
    python -m dribble_models.teacher_agreement A B --out models/teachers/detector-vs-observable.md

A policy drives both recordings and the teachers only label (DAgger's β = 0), so the robot
visits the same states in both wherever the closed loop repeats itself; a row is compared only
where its two thumbnails are the same bytes in both datasets (the same state, as the robot
sees it), and an episode's comparison stops at its first row that is not. A row is changed
where the two commands differ by more than 1e-6 in any component, or the phases differ. The
table gives, per phase of the first dataset's teacher, the rows compared and changed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .dataset import PHASES, DatasetError, load, read_index

#: Commands closer than this in every component are the same command.
SAME_COMMAND = 1e-6


def same_state_rows(first, second) -> int:
    """How many leading rows of two episodes of one seed show the same thumbnails."""
    n = min(len(first), len(second))
    for row in range(n):
        if not (np.array_equal(first.top[row], second.top[row]) and np.array_equal(first.bottom[row], second.bottom[row])):
            return row
    return n


def compare(first_dir: Path, second_dir: Path) -> dict:
    """Rows compared and changed, in all and per phase of the first teacher."""
    first, second = load(first_dir), load(second_dir)
    seeds = sorted(set(first.seeds()) & set(second.seeds()))
    if not seeds:
        raise DatasetError(f"{first_dir} and {second_dir} share no episode")
    compared = {phase: 0 for phase in PHASES}
    changed = {phase: 0 for phase in PHASES}
    recorded = 0
    for a, b in zip(first.subset(seeds), second.subset(seeds)):
        recorded += len(a)
        n = same_state_rows(a, b)
        differs = (np.abs(a.command[:n] - b.command[:n]) > SAME_COMMAND).any(axis=1) | (a.phase[:n] != b.phase[:n])
        for index, phase in enumerate(PHASES):
            mine = a.phase[:n] == index
            compared[phase] += int(mine.sum())
            changed[phase] += int((differs & mine).sum())
    return {
        "teachers": (read_index(first_dir).get("teacher"), read_index(second_dir).get("teacher")),
        "seeds": seeds,
        "recorded": recorded,
        "compared": compared,
        "changed": changed,
    }


def table(result: dict) -> str:
    first, second = result["teachers"]
    lines = [
        f"| phase ({first} teacher) | rows compared | rows the {second} teacher labels otherwise | share |",
        "|---|---|---|---|",
    ]
    for phase in (*PHASES, "all"):
        compared = sum(result["compared"].values()) if phase == "all" else result["compared"][phase]
        changed = sum(result["changed"].values()) if phase == "all" else result["changed"][phase]
        share = f"{changed / compared:.1%}" if compared else "-"
        lines.append(f"| {phase} | {compared} | {changed} | {share} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.teacher_agreement", description=__doc__.split("\n\n")[0])
    parser.add_argument("first", type=Path, help="a policy-driven dataset labelled by one teacher")
    parser.add_argument("second", type=Path, help="the same policy and seeds, labelled by the other")
    parser.add_argument("--out", type=Path, help="write the table here (Markdown) as well")
    args = parser.parse_args(argv)
    try:
        result = compare(args.first, args.second)
    except DatasetError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    seeds = result["seeds"]
    compared = sum(result["compared"].values())
    text = (
        f"Seeds {seeds[0]}..{seeds[-1]} ({len(seeds)} episodes), {result['recorded']} rows recorded, "
        f"{compared} of them the same state in both recordings.\n\n{table(result)}\n"
    )
    print(text, end="")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
