"""Two closed-loop runs of the same seeds side by side, seed by seed: each run's goals with its
Wilson interval, the seeds that end the same way, the goals only one of them scored, and the
exact two-sided McNemar test on those (is one run's goal rate other than the other's?).

    PYTHONPATH=models python -m dribble_models.paired_runs \\
        --run "4 samples" models/policy/NAME/select.json \\
        --run "1 sample" ~/.cache/dribble/samples-ab/select-clean-1.json \\
        --label "clean" --out models/performance/camera-samples-selection

Each run is a trajectories file of `dribble eval --trajectories` or its summary
(`dribble_models.eval_summary`): both list episodes with their seed and outcome. With
`--seeds A..B` (B excluded, as in `dribble eval --episodes`; the table prints the last seed
played) only those seeds are compared (both runs must hold every one of them): a
shorter run beside the first seeds of a longer one. Rows from
several calls collect in OUT.json (keyed by label) and OUT.md is rewritten from all of them.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from .cluster import seed_range
from .teachers import wilson


def outcomes(path: Path, seeds: range | None = None) -> dict[int, str]:
    """Seed -> outcome of every episode in a trajectories file or a summary (of `seeds` only,
    every one of which it must hold, when given)."""
    data = json.loads(path.read_text())
    episodes = data.get("episodes") if isinstance(data, dict) else None
    if not episodes:
        raise SystemExit(f"paired_runs: {path} lists no episodes")
    played = {int(e["seed"]): e["outcome"] for e in episodes}
    if seeds is None:
        return played
    missing = [s for s in seeds if s not in played]
    if missing:
        raise SystemExit(f"paired_runs: {path} holds no episode of the seeds {missing[:5]}")
    return {s: played[s] for s in seeds}


def mcnemar_p(only_first: int, only_second: int) -> float:
    """Exact two-sided McNemar p-value: under no difference, each discordant seed is a fair coin."""
    n = only_first + only_second
    if n == 0:
        return 1.0
    k = min(only_first, only_second)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2**n
    return min(1.0, 2 * tail)


def compare(first: dict[int, str], second: dict[int, str]) -> dict:
    """The paired comparison of two runs of the same seeds (refused when the seeds differ)."""
    if set(first) != set(second):
        missing = sorted(set(first) ^ set(second))
        raise SystemExit(f"paired_runs: the runs played other seeds ({missing[:5]} in only one)")
    seeds = sorted(first)
    goals = [sum(run[s] == "goal" for s in seeds) for run in (first, second)]
    only_first = sum(first[s] == "goal" != second[s] for s in seeds)
    only_second = sum(second[s] == "goal" != first[s] for s in seeds)
    return {
        # The first and last seed, as the results table names seed sets.
        "seeds": f"{seeds[0]}..{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1)) else seeds,
        "episodes": len(seeds),
        "goals": goals,
        "intervals": [[round(x, 2) for x in wilson(g, len(seeds))] for g in goals],
        "same_outcome": sum(first[s] == second[s] for s in seeds),
        "goal_only_first": only_first,
        "goal_only_second": only_second,
        "mcnemar_p": round(mcnemar_p(only_first, only_second), 3),
    }


def table(rows: dict[str, dict]) -> str:
    lines = ["| runs | seeds | first: goals (95 % interval) | second: goals (95 % interval) | same outcome | goal only in the first | goal only in the second | McNemar p |",
             "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for label, r in rows.items():
        (a, b), ((al, ah), (bl, bh)) = r["goals"], r["intervals"]
        n = r["episodes"]
        first, second = r["names"]
        lines.append(f"| {label}: {first} against {second} | {r['seeds']} | {a} / {n} ({al:.2f}-{ah:.2f}) | {b} / {n} ({bl:.2f}-{bh:.2f}) | "
                     f"{r['same_outcome']} of {n} | {r['goal_only_first']} | {r['goal_only_second']} | {r['mcnemar_p']:.2f} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.paired_runs", description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", nargs=2, action="append", metavar=("NAME", "FILE"), required=True, help="a run (twice): its name and its file")
    parser.add_argument("--label", required=True, help="the row's label (a row of the same label is replaced)")
    parser.add_argument("--out", type=Path, required=True, help="OUT.json collects the rows, OUT.md is their table")
    parser.add_argument("--seeds", type=seed_range, metavar="A..B", help="only these seeds, B excluded as in `dribble eval --episodes` (20000..20020: twenty seeds; the table prints the last one played); both runs must hold them all")
    args = parser.parse_args(argv)
    if len(args.run) != 2:
        parser.error("--run is given exactly twice")
    (first_name, first_file), (second_name, second_file) = args.run
    row = compare(outcomes(Path(first_file), args.seeds), outcomes(Path(second_file), args.seeds))
    row["names"] = [first_name, second_name]
    store = args.out.with_suffix(".json")
    rows = json.loads(store.read_text()) if store.is_file() else {}
    rows[args.label] = row
    store.parent.mkdir(parents=True, exist_ok=True)
    store.write_text(json.dumps(rows, indent=1) + "\n")
    text = table(rows)
    args.out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
