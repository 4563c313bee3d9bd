"""DAgger's iterations side by side: a table and a plot of goals and test error per iteration,
with behaviour cloning (iteration 0) and the paper's best numbers beside them.

    python -m dribble_models.dagger_report --base models/policy/cnn-modal \\
        --iteration DIR --iteration DIR ... --out DIR [--ship models/policy/dagger]

Every number is read from the files `scripts/dagger` leaves in each iteration's model
directory (`policy.toml`, `score_test.json`, `select.json`, and for the chosen iteration
`eval.json` and `fresh.json`) and from the rounds' `dataset.json`. `--chosen FILE` writes the
directory of the iteration with the most goals on the selection episodes (then the lowest
validation error; `shipping_rules.choose`); with `--ship` that iteration is copied there with the
table and plot. The test episodes play no part in either.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
from pathlib import Path

from .manifest import load
from .shipping_rules import Candidate, read_selection
from .shipping_rules import choose as choose_candidate

#: The paper's best test error (R-CNN) and most goals in 20 test episodes (R-CNN).
PAPER_TEST_ERROR = 0.14
PAPER_GOALS = 4

#: What a model directory keeps, and a shipped copy carries.
MODEL_FILES = ("policy.toml", "loss_curve.png", "scores.json", "score_train.json", "score_test.json", "eval.json", "fresh.json", "select.json", "eval_trajectories.png")


def read(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


def goals(summary: dict | None) -> tuple[int, int] | None:
    if summary is None:
        return None
    episodes = summary["episodes"]
    return sum(e["outcome"] == "goal" for e in episodes), len(episodes)


def iteration_row(number: int, directory: Path, rounds: Path | None) -> dict:
    manifest = load(directory / "policy.toml")
    training = manifest["training"]
    test = read(directory / "score_test.json")
    evaluation = read(directory / "eval.json")
    times = [e["duration_s"] for e in evaluation["episodes"] if e["outcome"] == "goal"] if evaluation else []
    row = {
        "iteration": number,
        "directory": str(directory),
        "validation_error": training.get("validation_error"),
        "test_error": test["error"] if test else training.get("test_error"),
        "goals": goals(evaluation),
        "held_out": goals(read(directory / "select.json")),
        "selection_seeds": seed_range(read(directory / "select.json")),
        "time_to_goal_s": statistics.median(times) if times else None,
        "training_wall_s": training.get("wall_time_s"),
        "datasets": 1 + len(training.get("added_datasets", [])),
    }
    round_index = read(rounds / f"round-{number}" / "dataset.json") if rounds and number > 0 else None
    if round_index:
        row["round_episodes"] = len(round_index["episodes"])
        row["round_rows"] = sum(e["rows"] for e in round_index["episodes"])
        row["round_goals"] = sum(e["outcome"] == "goal" for e in round_index["episodes"])
        row["beta"] = (round_index.get("driver") or {}).get("beta")
    return row


def seed_range(summary: dict | None) -> str | None:
    if summary is None:
        return None
    seeds = sorted(int(e["seed"]) for e in summary["episodes"])
    return f"{seeds[0]}..{seeds[-1]}"


def selection_label(rows: list[dict]) -> str:
    ranges = sorted({r["selection_seeds"] for r in rows if r.get("selection_seeds")})
    return "seeds " + ", ".join(ranges) if ranges else "none run"


def fmt(value, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def fraction(pair: tuple[int, int] | None) -> str:
    return "-" if pair is None else f"{pair[0]} / {pair[1]}"


def table(rows: list[dict]) -> str:
    lines = [
        f"| iteration | round recorded with (beta) | round: episodes, rows, goals | validation error | test error | goals (test) | median time to goal | goals (selection: {selection_label(rows)}) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        if row["iteration"] == 0:
            recorded = "behaviour cloning (the expert drives)"
            round_text = "-"
        else:
            recorded = f"iteration {row['iteration'] - 1}'s policy ({fmt(row.get('beta'), 4)})"
            round_text = f"{row.get('round_episodes', '-')}, {row.get('round_rows', '-')}, {row.get('round_goals', '-')}"
        seconds = fmt(row["time_to_goal_s"], 1) + " s" if row["time_to_goal_s"] is not None else "-"
        lines.append(
            f"| {row['iteration']} | {recorded} | {round_text} | {fmt(row['validation_error'])} | {fmt(row['test_error'])} "
            f"| {fraction(row['goals'])} | {seconds} | {fraction(row['held_out'])} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    iterations = [r["iteration"] for r in rows]
    figure, goal_axis = plt.subplots(figsize=(7, 4), dpi=120)
    test_goals = [r["goals"][0] if r["goals"] else float("nan") for r in rows]
    held_goals = [20 * r["held_out"][0] / r["held_out"][1] if r["held_out"] else float("nan") for r in rows]
    goal_axis.plot(iterations, test_goals, "o-", color="tab:green", label="goals, 20 test episodes")
    goal_axis.plot(iterations, held_goals, "s--", color="tab:olive", label=f"goals, selection ({selection_label(rows)}), per 20")
    goal_axis.axhline(PAPER_GOALS, color="tab:green", linestyle=":", linewidth=1, label=f"paper's best: {PAPER_GOALS} goals")
    goal_axis.set_xlabel("DAgger iteration (0: behaviour cloning)")
    goal_axis.set_ylabel("goals per 20 episodes", color="tab:green")
    goal_axis.set_ylim(0, 20)
    goal_axis.set_xticks(iterations)
    error_axis = goal_axis.twinx()
    errors = [r["test_error"] if r["test_error"] is not None else float("nan") for r in rows]
    error_axis.plot(iterations, errors, "^-", color="tab:red", label="test error")
    error_axis.axhline(PAPER_TEST_ERROR, color="tab:red", linestyle=":", linewidth=1, label=f"paper's best: {PAPER_TEST_ERROR}")
    error_axis.set_ylabel("test error (paper metric)", color="tab:red")
    error_axis.set_ylim(0, max(0.3, max((e for e in errors if e == e), default=0.3) * 1.2))
    handles = goal_axis.get_legend_handles_labels()[0] + error_axis.get_legend_handles_labels()[0]
    labels = goal_axis.get_legend_handles_labels()[1] + error_axis.get_legend_handles_labels()[1]
    goal_axis.legend(handles, labels, loc="upper left", fontsize=7)
    goal_axis.set_title(title, fontsize=9)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def choose(rows: list[dict]) -> dict:
    """The iteration to ship, by the one rule of `shipping_rules.choose` (selection goals, then
    validation error) on each iteration's select.json."""
    candidates = [
        Candidate(
            name=str(row["iteration"]),
            selection=read_selection(Path(row["directory"]) / "select.json"),
            validation_error=row["validation_error"],
        )
        for row in rows
    ]
    chosen = choose_candidate(candidates)
    return next(row for row in rows if str(row["iteration"]) == chosen.name)


def ship_target(pattern: str, iteration: int) -> Path:
    """Where the chosen iteration goes: `pattern` with `{iteration}` replaced. A model
    directory there that no DAgger run shipped (no ITERATION file: a model trained some other
    way that happens to carry the name) is never overwritten."""
    target = Path(pattern.replace("{iteration}", str(iteration)))
    if (target / "policy.toml").is_file() and not (target / "ITERATION").is_file():
        raise ValueError(f"{target} holds a model no DAgger run shipped; ship elsewhere (--ship)")
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.dagger_report", description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", type=Path, required=True, help="the behaviour-cloned model DAgger started from (iteration 0)")
    parser.add_argument("--iteration", type=Path, action="append", default=[], help="an iteration's model directory, in order")
    parser.add_argument("--rounds", type=Path, help="directory of the rounds' datasets (round-<i>/), for their beta, rows and goals")
    parser.add_argument("--out", type=Path, required=True, help="where dagger.md and dagger.png go")
    parser.add_argument("--chosen", type=Path, help="write the chosen iteration's directory into this file")
    parser.add_argument(
        "--ship",
        help="copy the chosen iteration here, with the table and the plot; `{iteration}` in it becomes the chosen "
        "iteration's number (models/policy/cnn-dagger{iteration}-observable: the name says how many rounds it learned from)",
    )
    args = parser.parse_args(argv)
    present = [d for d in args.iteration if (d / "policy.toml").is_file()]
    if len(present) < len(args.iteration):
        missing = [str(d) for d in args.iteration if d not in present]
        print(f"not trained yet, left out: {', '.join(missing)}", file=sys.stderr)
    rows = [iteration_row(0, args.base, None)] + [iteration_row(i + 1, d, args.rounds) for i, d in enumerate(present)]
    text = table(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "dagger.md").write_text(text)
    (args.out / "dagger.json").write_text(json.dumps(rows, indent=1) + "\n")
    plot(rows, args.out / "dagger.png", f"DAgger from {args.base.name}")
    print(text)
    if args.chosen is not None and len(rows) > 1:
        args.chosen.write_text(choose(rows[1:])["directory"] + "\n")
    if args.ship is not None and len(rows) > 1:
        chosen = choose(rows[1:])
        source = Path(chosen["directory"])
        try:
            args.ship = ship_target(args.ship, chosen["iteration"])
        except ValueError as error:
            print(f"dagger_report: {error}", file=sys.stderr)
            return 2
        args.ship.mkdir(parents=True, exist_ok=True)
        for stale in args.ship.glob("*.onnx"):
            stale.unlink()
        for name in MODEL_FILES:
            if (source / name).is_file():
                shutil.copy2(source / name, args.ship / name)
        for network in source.glob("*.onnx"):
            shutil.copy2(network, args.ship / network.name)
        for name in ("dagger.md", "dagger.json", "dagger.png"):
            shutil.copy2(args.out / name, args.ship / name)
        (args.ship / "ITERATION").write_text(f"{chosen['iteration']}\n")
        print(f"shipped iteration {chosen['iteration']} ({fraction(chosen['held_out'])} held-out goals) to {args.ship}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
