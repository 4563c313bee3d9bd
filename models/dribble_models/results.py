"""The results table: the paper's numbers beside ours, from the files `scripts/train` writes.

    python -m dribble_models.results --row "CNN (paper setup)=models/policy/cnn" ... --out FILE

Each model directory holds `policy.toml`, `scores.json` (the trainer's errors),
`score_train.json` and `score_test.json` (`dribble score`, the robot's code) and
`eval.json` (the 20 test episodes in closed loop, summarised by `eval_summary`). Every number in the
table is read from those files; nothing is typed in but the paper's own row.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

from .dataset import PHASES
from .manifest import load
from .selection import Candidate, read_selection
from .selection import choose as choose_candidate

#: Table 1 of the paper and its text (forward pass on a laptop i7; none given for the H-CNN).
PAPER = [
    ("CNN (paper)", 0.12, 0.16, 3, "1.8 ms (i7)"),
    ("H-CNN (paper)", 0.15, 0.17, 3, "-"),
    ("R-CNN (paper)", 0.036, 0.14, 4, "2.1 ms (i7)"),
]


def read(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


def model_row(name: str, directory: Path) -> dict:
    manifest = load(directory / "policy.toml")
    train, test = read(directory / "score_train.json"), read(directory / "score_test.json")
    evaluation = read(directory / "eval.json")
    row = {"name": name, "directory": str(directory), "kind": manifest["kind"], "training": manifest["training"]}
    row["train_error"] = train["error"] if train else manifest["training"].get("train_error")
    row["test_error"] = test["error"] if test else manifest["training"].get("test_error")
    row["phases"] = {p: (test["phases"][p]["error"] if test else None) for p in PHASES}
    row["step_ms"] = test["step_ms"]["median"] if test else None
    # Scores written before `dribble score` named its engine were all run under tract; the
    # compiled engine's name carries its instruction set, e.g. "compiled (avx2+fma)".
    row["engine"] = (test.get("engine") or "tract") if test else None
    if evaluation:
        episodes = evaluation["episodes"]
        goals = [e["duration_s"] for e in episodes if e["outcome"] == "goal"]
        row["goals"], row["episodes"] = len(goals), len(episodes)
        row["time_to_goal_s"] = statistics.median(goals) if goals else None
    # The engine that ran the policy in the closed loop; summaries written before `dribble
    # eval` recorded it do not say (a closed loop amplifies an engine's rounding into other
    # episodes, so goal counts belong to the engine that measured them).
    row["closed_loop_engine"] = (evaluation or {}).get("engine") or "not recorded"
    return row


def fmt(value, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def table(rows: list[dict]) -> str:
    lines = [
        "| model | training | error, seeds 0..99 (fitted and validation) | validation error (seeds 90..99) | test error | goals /20 (test) | median time to goal | goals /10 (selection: seeds 90..99) | closed loop run by | forward pass |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, train, test, goals, forward in PAPER:
        lines.append(f"| {name} | paper: Adam, 100 episodes | {train} | - | {test} | {goals} | - | - | - | {forward} |")
    for row in rows:
        t = row["training"]
        how = f"{t['epochs']} epochs (kept {t.get('best_epoch', '-')}), {t.get('wall_time_s', 0) / 60:.0f} min"
        goals = f"{row['goals']}" if "goals" in row else "-"
        seconds = f"{row['time_to_goal_s']:.1f} s" if row.get("time_to_goal_s") else "-"
        forward = f"{row['step_ms']:.2f} ms ({row['engine']}, 1 core of this machine)" if row["step_ms"] else "-"
        selection = read(Path(row["directory"]) / "select.json")
        held_out = f"{sum(e['outcome'] == 'goal' for e in selection['episodes'])}" if selection else "-"
        validation = fmt(t.get("validation_error"))
        lines.append(
            f"| {row['name']} | {how} | {fmt(row['train_error'])} | {validation} | {fmt(row['test_error'])} | {goals} | {seconds} | {held_out} | {row['closed_loop_engine']} | {forward} |"
        )
    return "\n".join(lines)


def phase_table(rows: list[dict]) -> str:
    lines = ["| model | " + " | ".join(PHASES) + " |", "|---|" + "---|" * len(PHASES)]
    for row in rows:
        lines.append(f"| {row['name']} | " + " | ".join(fmt(row["phases"][p]) for p in PHASES) + " |")
    return "\n".join(lines)


def failure_analysis(rows: list[dict]) -> str:
    """Where the episodes without a goal ended, from `eval.json` (eval_summary): did the
    robot ever reach the ball (within 0.3 m), did the ball move toward the target goal, and
    how the episode ended."""
    lines = [
        "| model | failed | outcome (time limit / ball out / other) | reached the ball | ball moved >0.5 m toward goal | median ball distance to goal at the end | median share of the episode standing |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        evaluation = read(Path(row["directory"]) / "eval.json")
        if not evaluation:
            continue
        failed = [e for e in evaluation["episodes"] if e["outcome"] != "goal"]
        outcomes = {"time_limit": 0, "ball_out": 0}
        for e in failed:
            outcomes[e["outcome"]] = outcomes.get(e["outcome"], 0) + 1
        reached = sum(e["closest_to_ball_m"] < 0.3 for e in failed)
        toward = sum(e["ball_toward_goal_m"] > 0.5 for e in failed)
        ends = [e["ball_to_goal_end_m"] for e in failed]
        other = len(failed) - outcomes["time_limit"] - outcomes["ball_out"]
        median_end = f"{statistics.median(ends):.2f} m" if ends else "-"
        standing = [e["standing_share"] for e in failed]
        median_standing = f"{statistics.median(standing):.0%}" if standing else "-"
        lines.append(
            f"| {row['name']} | {len(failed)} | {outcomes['time_limit']} / {outcomes['ball_out']} / {other} | {reached} | {toward} | {median_end} | {median_standing} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.results", description=__doc__.split("\n\n")[0])
    parser.add_argument("--row", action="append", default=[], help="NAME=MODEL_DIRECTORY, in table order")
    parser.add_argument("--out", type=Path, help="also write the tables (Markdown) here")
    parser.add_argument("--choose", type=Path, help="write the chosen model's directory name here: most goals on the selection episodes (select.json), then lowest validation error")
    args = parser.parse_args(argv)
    rows = []
    for spec in args.row:
        name, _, directory = spec.partition("=")
        if not (Path(directory) / "policy.toml").is_file():
            print(f"error: {directory} holds no policy.toml", file=sys.stderr)
            return 2
        rows.append(model_row(name, Path(directory)))
    text = "\n".join(
        [
            table(rows),
            "",
            "Test error per expert phase (`dribble score` on the 20 test episodes):",
            "",
            phase_table(rows),
            "",
            "Episodes without a goal (closed loop, 20 test episodes; from the trajectories):",
            "",
            failure_analysis(rows),
            "",
        ]
    )
    print(text)
    if args.out:
        args.out.write_text(text)
    if args.choose and rows:
        chosen = choose(rows)
        args.choose.write_text(Path(chosen["directory"]).name + "\n")
        print(f"shipped: {chosen['directory']} ({chosen['selection']})")
    return 0


def choose(rows: list[dict]) -> dict:
    """The shipped row, by the one rule of `selection.choose` on each row's select.json.
    Never the test episodes: they are for reporting only."""
    candidates = {
        Path(row["directory"]).name: Candidate(
            name=Path(row["directory"]).name,
            selection=read_selection(Path(row["directory"]) / "select.json"),
            validation_error=row["training"].get("validation_error"),
        )
        for row in rows
    }
    chosen = choose_candidate(list(candidates.values()))
    for row in rows:
        row["selection"] = candidates[Path(row["directory"]).name].reason()
    return next(row for row in rows if Path(row["directory"]).name == chosen.name)


if __name__ == "__main__":
    sys.exit(main())
