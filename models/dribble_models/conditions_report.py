"""How policies hold up under the conditions a real field brings: the table and the picture,
generated from the summaries `scripts/conditions` leaves in models/conditions/, never typed.

    python -m dribble_models.conditions_report            # models/conditions/README.md, shipped.png
    python -m dribble_models.conditions_report --frames   # and models/conditions/frames.png

Per policy and seed set (models/conditions/<policy>/<seed set>/<condition>-<severity>.json):
goals with their Wilson 95 % interval, the ratio to the same policy's clean goals on the same
seeds, and the failure classes of the episodes without a goal. The clean reference is a
`clean.json` beside them where a run left one, else the policy's own clean closed loop on
those seeds (models/policy/<policy>/fresh.json for fresh seeds, select.json for the
selection seeds, eval.json for the test seeds), measured by the same engine.

shipped.png draws the shipped policies' rows (models/policy/HOST_MODEL, ROBOT_MODEL) on the
fresh seeds: each condition's ratio to clean at each severity played, from the hundred fresh
seeds where a condition was played on them and the first twenty otherwise, beside issue 48's
target (0.90 of clean) and floor (0.75).

The picture shows what the top camera's thumbnail (what the network sees) looks like under
each condition at severities 1, 3 and 5, rendered by `dribble render` on a selection seed.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

from .eval_summary import FAILURE_CLASSES, class_of
from .teachers import wilson

#: The conditions in the order the simulator lists them (sim-harness/src/conditions).
CONDITIONS = [
    "exposure",
    "contrast",
    "noise",
    "white-balance",
    "motion-blur",
    "lens",
    "light",
    "venue",
    "unseen-venue",
    "robots",
]
#: Where a seed set's clean closed loop lives in a policy's directory, by the seed set's name
#: (fresh, fresh20: fresh.json; selection, selection25, selection-first-9: select.json; test:
#: eval.json); it is cut to the seeds the condition runs played.
CLEAN_SOURCES = {"fresh": "fresh.json", "selection": "select.json", "test": "eval.json"}

#: The shipped policies drawn in shipped.png, by the file in models/policy naming each.
SHIPPED = (("HOST_MODEL", "host model"), ("ROBOT_MODEL", "robot package"))
#: What a shipped policy's panel says before any condition is played on its fresh seeds (a
#: policy just shipped: its conditions are a function of the policy and start empty).
NOT_PLAYED = "no condition played on the fresh seeds yet (scripts/conditions --seeds fresh20)"
#: Issue 48's target and floor for a condition's goals, as shares of clean goals.
TARGET_RATIO, FLOOR_RATIO = 0.90, 0.75

#: The frame in the picture: a selection seed, a second and a half into a walk and turn.
PICTURE_SEED = 20_003
SEVERITIES_PICTURED = (1, 3, 5)

ROOT = Path(__file__).resolve().parents[2]


class ReportError(Exception):
    """Summaries that cannot be compared."""


def goals_of(summary: dict) -> tuple[int, int]:
    episodes = summary["episodes"]
    return sum(e["outcome"] == "goal" for e in episodes), len(episodes)


def clean_reference(policy_dir: Path, seed_set: str, runs: Path) -> dict | None:
    """The policy's clean summary on the seeds its condition runs in `runs` played: a
    `clean.json` there, else its own clean closed loop (CLEAN_SOURCES) cut to those seeds."""
    own = runs / "clean.json"
    if own.is_file():
        return json.loads(own.read_text())
    source = next((file for prefix, file in CLEAN_SOURCES.items() if seed_set.startswith(prefix)), None)
    played = [json.loads(p.read_text()) for p in sorted(runs.glob("*.json"))]
    if source is None or not played or not (policy_dir / source).is_file():
        return None
    seeds = {e["seed"] for e in played[0]["episodes"]}
    summary = json.loads((policy_dir / source).read_text())
    episodes = [e for e in summary["episodes"] if e["seed"] in seeds]
    if len(episodes) != len(seeds):
        return None
    return {"engine": summary.get("engine"), "episodes": episodes}


def condition_rows(runs: Path, clean: dict | None) -> list[dict]:
    rows = []
    for path in sorted(runs.glob("*.json"), key=order):
        if path.name == "clean.json":
            continue
        summary = json.loads(path.read_text())
        goals, episodes = goals_of(summary)
        if clean is not None and clean.get("engine") != summary.get("engine"):
            raise ReportError(f"{path} ran on {summary.get('engine')}, its clean reference on {clean.get('engine')}")
        if summary.get("camera_samples", 4) != 4:
            raise ReportError(f"{path} saw frames of {summary['camera_samples']} camera sample(s) a pixel; the tables compare the 4-sample frames every model was trained on")
        if clean is not None:
            clean_seeds = sorted(e["seed"] for e in clean["episodes"])
            if clean_seeds != sorted(e["seed"] for e in summary["episodes"]):
                raise ReportError(f"{path} and its clean reference played other seeds")
        failures = Counter(class_of(e) for e in summary["episodes"] if e["outcome"] != "goal")
        condition, _, severity = path.stem.rpartition("-")
        rows.append(
            {
                "condition": condition if severity.isdigit() else path.stem,
                "severity": int(severity) if severity.isdigit() else None,
                "goals": goals,
                "episodes": episodes,
                "failures": failures,
                "engine": summary.get("engine"),
            }
        )
    return rows


def order(path: Path) -> tuple[int, int]:
    condition, _, severity = path.stem.rpartition("-")
    index = CONDITIONS.index(condition) if condition in CONDITIONS else len(CONDITIONS)
    return index, int(severity) if severity.isdigit() else 0


def interval(goals: int, episodes: int) -> str:
    low, high = wilson(goals, episodes)
    return f"{goals} / {episodes} ({low:.2f}-{high:.2f})"


def failure_text(failures: Counter) -> str:
    if not failures:
        return "-"
    return ", ".join(f"{name.replace('_', ' ')} {count}" for name, count in failures.most_common())


def table(policy: str, seed_set: str, clean: dict | None, rows: list[dict]) -> str:
    lines = [
        f"### {policy} on the {seed_set} seeds",
        "",
        "| condition | severity | goals (95 % interval) | ratio to clean | failures |",
        "|---|---|---|---|---|",
    ]
    clean_rate = None
    if clean is not None:
        goals, episodes = goals_of(clean)
        clean_rate = goals / episodes if episodes else None
        failures = Counter(class_of(e) for e in clean["episodes"] if e["outcome"] != "goal")
        lines.append(f"| clean | - | {interval(goals, episodes)} | 1.00 | {failure_text(failures)} |")
    for row in rows:
        ratio = "-" if not clean_rate else f"{row['goals'] / row['episodes'] / clean_rate:.2f}"
        severity = "-" if row["severity"] is None else str(row["severity"])
        lines.append(f"| {row['condition']} | {severity} | {interval(row['goals'], row['episodes'])} | {ratio} | {failure_text(row['failures'])} |")
    engines = sorted({str(row["engine"]) for row in rows})
    lines += ["", f"Engine: {', '.join(engines)}."]
    return "\n".join(lines)


def report(root: Path, policies: Path) -> str:
    parts = [
        "# Policies under conditions",
        "",
        "Generated by `python -m dribble_models.conditions_report` from the summaries `scripts/conditions` "
        "leaves here; do not edit. Each condition (sim-harness/src/conditions) is applied at the cameras' "
        "own resolution before YUYV packing, its random draws taken from the episode's seed. Goals with "
        "their Wilson 95 % interval; the ratio is to the same policy's clean goals on the same seeds with "
        "the same engine. Fresh and test seeds are for reporting only; choices are made on the selection seeds.",
        "",
        "Failure classes (`dribble_models.eval_summary`, from each episode's paths): "
        + "; ".join(f"*{name.replace('_', ' ')}*: {meaning}" for name, meaning in FAILURE_CLASSES.items())
        + ".",
        "",
        "![The top camera's thumbnail under each condition](frames.png)",
        "",
        "![The shipped policies' goals under each condition as a share of their clean goals on the "
        "fresh seeds](shipped.png)",
    ]
    for policy_dir in sorted(p for p in root.iterdir() if p.is_dir()):
        for runs in sorted(p for p in policy_dir.iterdir() if p.is_dir()):
            clean = clean_reference(policies / policy_dir.name, runs.name, runs)
            rows = condition_rows(runs, clean)
            if rows:
                parts += ["", table(policy_dir.name, runs.name, clean, rows)]
    return "\n".join(parts) + "\n"


def ratio_points(root: Path, policies: Path, policy: str) -> list[dict]:
    """A policy's ratio to clean under each condition and severity played on the fresh seeds,
    with the Wilson 95 % interval of its goal rate divided by the clean rate (the clean count's
    own spread left out): from the hundred fresh seeds where they were played, else the first
    twenty. Its fresh clean goals must be known; rows without them, and runs of a mix such as
    `randomized`, are left out."""
    points: dict[tuple[str, int], dict] = {}
    for seed_set in ("fresh20", "fresh"):  # the hundred replace the twenty where both exist
        runs = root / policy / seed_set
        if not runs.is_dir():
            continue
        clean = clean_reference(policies / policy, seed_set, runs)
        if clean is None:
            continue
        clean_goals, clean_episodes = goals_of(clean)
        if clean_goals == 0:
            continue
        clean_rate = clean_goals / clean_episodes
        for row in condition_rows(runs, clean):
            if row["severity"] is None or row["condition"] not in CONDITIONS:
                continue
            low, high = wilson(row["goals"], row["episodes"])
            points[(row["condition"], row["severity"])] = {
                "condition": row["condition"],
                "severity": row["severity"],
                "ratio": row["goals"] / row["episodes"] / clean_rate,
                "low": low / clean_rate,
                "high": high / clean_rate,
                "episodes": row["episodes"],
            }
    return sorted(points.values(), key=lambda p: (CONDITIONS.index(p["condition"]), p["severity"]))


def plot_shipped(root: Path, policies: Path, out: Path) -> None:
    """shipped.png: one panel a shipped policy, a marker a condition and severity (filled where
    played on the hundred fresh seeds), the target and the floor as lines."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    figure, axes = plt.subplots(len(SHIPPED), 1, figsize=(9, 3.2 * len(SHIPPED)), dpi=110, sharex=True)
    colours = {1: "tab:green", 2: "tab:olive", 3: "tab:blue", 4: "tab:purple", 5: "tab:red"}
    for axis, (file, role) in zip(axes, SHIPPED):
        policy = (policies / file).read_text().strip()
        points = ratio_points(root, policies, policy)
        severities = sorted({p["severity"] for p in points})
        for severity in severities:
            shift, colour = (severity - 3) * 0.12, colours.get(severity, "grey")
            mine = [p for p in points if p["severity"] == severity]
            x = [CONDITIONS.index(p["condition"]) + shift for p in mine]
            axis.errorbar(
                x, [p["ratio"] for p in mine], yerr=[[p["ratio"] - p["low"] for p in mine], [p["high"] - p["ratio"] for p in mine]],
                fmt="none", ecolor=colour, alpha=0.5, linewidth=1,
            )
            for xi, p in zip(x, mine):
                axis.plot(xi, p["ratio"], "o", color=colour, markerfacecolor=colour if p["episodes"] >= 100 else "white")
            axis.plot([], [], "o", color=colour, label=f"severity {severity}")
        if not points:
            axis.text(
                0.5, 0.3, NOT_PLAYED, transform=axis.transAxes, ha="center", va="center", fontsize=9, color="grey",
            )
        axis.axhline(1.0, color="black", linewidth=0.8)
        axis.axhline(TARGET_RATIO, color="tab:orange", linestyle="--", linewidth=1, label=f"target {TARGET_RATIO:.2f}")
        axis.axhline(FLOOR_RATIO, color="tab:red", linestyle=":", linewidth=1, label=f"floor {FLOOR_RATIO:.2f}")
        axis.set_ylim(min([0.3] + [p["low"] - 0.05 for p in points]), 1.25)
        axis.set_ylabel("goals / clean goals")
        axis.set_title(f"{role}: {policy}", fontsize=8)
        axis.legend(loc="lower left", fontsize=7, ncol=5)
    axes[-1].set_xticks(range(len(CONDITIONS)))
    axes[-1].set_xticklabels(CONDITIONS, rotation=30, ha="right", fontsize=8)
    figure.text(
        0.01, 0.005,
        "Fresh seeds: filled, all 100; open, the first 20. Bars: the Wilson 95 % interval of the condition's goal rate over the clean rate.",
        fontsize=7,
    )
    figure.tight_layout(rect=(0, 0.02, 1, 1))
    figure.savefig(out, metadata={"Software": None})
    plt.close(figure)


def render_frames(dribble: Path, out: Path) -> None:
    """A grid of the top thumbnail under each condition at severities 1, 3 and 5 (and clean)."""
    from PIL import Image, ImageDraw

    scale, width, height, label = 2, 160, 120, 130
    columns = len(SEVERITIES_PICTURED)
    sheet = Image.new("RGB", (label + columns * width * scale, (len(CONDITIONS) + 1) * height * scale + 24), "white")
    draw = ImageDraw.Draw(sheet)
    for c, severity in enumerate(SEVERITIES_PICTURED):
        draw.text((label + c * width * scale + 8, 6), f"severity {severity}", fill="black")
    with tempfile.TemporaryDirectory() as scratch:
        for r, condition in enumerate(["clean", *CONDITIONS]):
            draw.text((6, 24 + r * height * scale + height * scale // 2), condition, fill="black")
            for c, severity in enumerate(SEVERITIES_PICTURED):
                if condition == "clean" and c > 0:
                    continue
                text = "clean" if condition == "clean" else f"{condition}:{severity}"
                target = Path(scratch) / text.replace(":", "-")
                subprocess.run(
                    [str(dribble), "render", "--seed", str(PICTURE_SEED), "--seconds", "1.5", "--forward", "0.6", "--turn", "0.8", "--condition", text, "--out", str(target)],
                    check=True,
                    capture_output=True,
                )
                thumbnail = Image.open(target / "top_thumbnail.png").convert("RGB").resize((width * scale, height * scale))
                sheet.paste(thumbnail, (label + c * width * scale, 24 + r * height * scale))
    sheet.save(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.conditions_report", description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=ROOT / "models" / "conditions", help="where scripts/conditions keeps the summaries")
    parser.add_argument("--policies", type=Path, default=ROOT / "models" / "policy", help="the policies' directories (their clean runs)")
    parser.add_argument("--frames", action="store_true", help="also render the picture (needs the dribble binary)")
    parser.add_argument("--dribble", type=Path, default=Path.home() / ".cache" / "dribble" / "target" / "release" / "dribble", help="the dribble binary for --frames")
    parser.add_argument("--check", action="store_true", help="fail if README.md differs from what the summaries give")
    args = parser.parse_args(argv)
    try:
        text = report(args.root, args.policies)
    except (ReportError, OSError, ValueError, KeyError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    readme = args.root / "README.md"
    if args.check:
        if not readme.is_file() or readme.read_text() != text:
            print(f"error: {readme} is not what the summaries give: run python -m dribble_models.conditions_report", file=sys.stderr)
            return 1
        return 0
    args.root.mkdir(parents=True, exist_ok=True)
    readme.write_text(text)
    print(f"wrote {readme}")
    if all((args.policies / file).is_file() for file, _ in SHIPPED):
        plot_shipped(args.root, args.policies, args.root / "shipped.png")
        print(f"wrote {args.root / 'shipped.png'}")
    if args.frames:
        render_frames(args.dribble, args.root / "frames.png")
        print(f"wrote {args.root / 'frames.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
