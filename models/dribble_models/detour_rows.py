"""What policies send where the teacher walks around the ball, offline (issue 48's standstill).

    python -m dribble_models.detour_rows --dataset ~/.cache/dribble/data/randomized-detector \\
        --seeds 54..60 models/policy/cnn-conditions-motion-light models/policy/CANDIDATE

The most common miss of the conditions models is the standstill beside the ball
(`eval_summary`'s "stood at the ball"): standing on the ball's goal side, facing a wall, the
teacher walks around the ball on the side of the ball-to-goal line it stands on, and where
the images do not show that side a regression on both answers their mean, nothing. This
finds those rows in recorded episodes (the teacher's two-way detour, recomputed from the
ground truth: `OneWayDetour.detour_rows`), keeps the ones where the target goal lies outside
the top camera's view (bearing beyond `OUT_OF_VIEW_RAD`: the side cannot be read off the
goal), and prints for each policy, run by onnxruntime on the rows' thumbnails: the command
error (the trainer's metric), the mean size of the sideways command it sends beside the
teacher's, the share of rows where it steps sideways (beyond `STEP`) the teacher's way, the
other way, and where it stands (every component under `STEP`). A proxy on the teacher's
states, not the policy's own; the selection seeds choose. Rows must come from training or
validation seeds (`seed_ranges.refuse_reserved`).

`--driven` reads a policy-driven DAgger round (`dribble dagger`, which records the driving
policy's own command beside the teacher's label on every row) instead of running policies:
what the policy that drove sent on its own states, where the teacher walks around the ball,
on all such rows and apart on the rows at the ball (within `AT_BALL_M`), where a step forward
pushes the ball along instead of going around it ("carried while going around",
dribble_models.ball_out):

    python -m dribble_models.detour_rows --driven \\
        --dataset ~/.cache/dribble/data-dagger/4-cnn-conditions-previous-whole-venue-light-4-16-4-8-int8 --seeds 4000..4040
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from . import dataset, seed_ranges
from .cluster import seed_range
from .command_metric import row_errors, sent_commands
from .gym_equivalence import OnnxPolicy
from .one_way_detour import AT_BALL_M, OneWayDetour

#: Half the top camera's horizontal field of view (about 61 degrees), radians: a goal whose
#: bearing lies beyond it is out of the image.
OUT_OF_VIEW_RAD = 0.53
#: A command component beyond this (normalised units) is a step; under it on every axis, a stand.
STEP = 0.15


def goal_bearings(episode: dataset.Episode, rows: np.ndarray) -> np.ndarray:
    """The target goal's bearing from the robot's heading at `rows`, radians (-pi..pi)."""
    detour = OneWayDetour()
    side = 1.0 if episode.ball[0, 0] >= 0.0 else -1.0
    pose = episode.robot_pose[rows].astype(np.float64)
    bearing = np.arctan2(-pose[:, 1], side * detour.goal_x - pose[:, 0]) - pose[:, 2]
    return (bearing + math.pi) % (2.0 * math.pi) - math.pi


def aliased_rows(episodes: list[dataset.Episode]) -> list[tuple[dataset.Episode, np.ndarray]]:
    """Each episode with the indices of its detour rows whose target goal is out of view."""
    out = []
    for episode in episodes:
        mask, _ = OneWayDetour().detour_rows(episode)
        rows = np.flatnonzero(mask)
        rows = rows[np.abs(goal_bearings(episode, rows)) > OUT_OF_VIEW_RAD]
        out.append((episode, rows))
    return out


def behaviour(sent: np.ndarray, teacher: np.ndarray) -> dict:
    """Error and the sideways figures of `sent` commands against the `teacher`'s (module doc)."""
    stepping = np.abs(sent[:, 1]) > STEP
    same_way = np.sign(sent[:, 1]) == np.sign(teacher[:, 1])
    return {
        "error": float(row_errors(sent, teacher).mean()),
        "forward": float(sent[:, 0].mean()),
        "teacher_forward": float(teacher[:, 0].mean()),
        "sideways_size": float(np.abs(sent[:, 1]).mean()),
        "teacher_sideways_size": float(np.abs(teacher[:, 1]).mean()),
        "teachers_way": float((stepping & same_way).mean()),
        "other_way": float((stepping & ~same_way).mean()),
        "stands": float((np.abs(sent) < STEP).all(axis=1).mean()),
    }


def study(policies: list[Path], episodes: list[dataset.Episode]) -> dict:
    """Per policy, `behaviour` on the aliased detour rows of `episodes`."""
    chosen = [(e, rows) for e, rows in aliased_rows(episodes) if len(rows)]
    teacher = np.concatenate([e.command[rows] for e, rows in chosen]) if chosen else np.zeros((0, 3), np.float32)
    table = {"rows": int(len(teacher)), "policies": {}}
    if not chosen:
        return table
    for policy in policies:
        network = OnnxPolicy(policy / "policy.toml")
        outputs = np.array([network({"top": e.top[i], "bottom": e.bottom[i]}) for e, rows in chosen for i in rows])
        table["policies"][policy.name] = behaviour(sent_commands(outputs), teacher)
    return table


def recorded_policy_commands(directory: Path, seeds: list[int]) -> dict[int, np.ndarray]:
    """The driving policy's commands [T, 3] of a policy-driven recording, by seed, as sent."""
    index = dataset.read_index(Path(directory))
    wanted = set(seeds)
    commands = {}
    for entry in index["episodes"]:
        if entry["seed"] not in wanted:
            continue
        with np.load(Path(directory) / entry["file"]) as arrays:
            if "policy_command" not in arrays.files:
                raise dataset.DatasetError(
                    f"{Path(directory) / entry['file']}: no policy_command (teacher-driven, not a DAgger round): --driven reads a policy-driven recording"
                )
            commands[int(entry["seed"])] = sent_commands(arrays["policy_command"])
    return commands


def driven_study(episodes: list[dataset.Episode], driven: dict[int, np.ndarray]) -> dict:
    """`behaviour` of the recorded driving commands on every detour row, at the ball, and
    with the target goal out of view (module doc, `--driven`)."""
    sent, teacher, at_ball, out_of_view = [], [], [], []
    for episode in episodes:
        mask, _ = OneWayDetour().detour_rows(episode)
        rows = np.flatnonzero(mask)
        if not len(rows):
            continue
        pose, ball = episode.robot_pose[rows].astype(np.float64), episode.ball[rows].astype(np.float64)
        at_ball.append(np.hypot(ball[:, 0] - pose[:, 0], ball[:, 1] - pose[:, 1]) < AT_BALL_M)
        out_of_view.append(np.abs(goal_bearings(episode, rows)) > OUT_OF_VIEW_RAD)
        sent.append(driven[episode.seed][rows])
        teacher.append(episode.command[rows])
    if not sent:
        return {"rows": 0, "groups": {}}
    sent, teacher = np.concatenate(sent), np.concatenate(teacher)
    at_ball, out_of_view = np.concatenate(at_ball), np.concatenate(out_of_view)
    groups = {
        "every detour row": np.ones(len(sent), bool),
        "target goal out of view": out_of_view,
        f"at the ball (within {AT_BALL_M} m)": at_ball,
        "at the ball, target goal out of view": at_ball & out_of_view,
    }
    return {
        "rows": int(len(sent)),
        "groups": {name: {"rows": int(m.sum()), **behaviour(sent[m], teacher[m])} for name, m in groups.items() if m.any()},
    }


def behaviour_cells(b: dict) -> str:
    """`behaviour`'s figures as the table cells both tables share."""
    return (
        f"{b['error']:.3f} | {b['forward']:+.2f} ({b['teacher_forward']:+.2f}) | {b['sideways_size']:.2f} ({b['teacher_sideways_size']:.2f}) | "
        f"{b['teachers_way']:.0%} | {b['other_way']:.0%} | {b['stands']:.0%}"
    )


def driven_markdown(table: dict, seeds: list[int], directory: Path) -> str:
    lines = [
        f"The driving policy's recorded commands on {table['rows']} rows of the teacher's detour, {directory.name}, seeds {seeds[0]}..{seeds[-1] + 1}",
        "",
        "| rows | how many | error | forward (teacher's) | sideways size (teacher's) | steps the teacher's way | the other way | stands |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [f"| {name} | {b['rows']} | {behaviour_cells(b)} |" for name, b in table["groups"].items()]
    return "\n".join(lines)


def markdown(table: dict, seeds: list[int]) -> str:
    lines = [
        f"{table['rows']} rows of the teacher's detour with the target goal out of view, seeds {seeds[0]}..{seeds[-1] + 1}",
        "",
        "| policy | error | forward (teacher's) | sideways size (teacher's) | steps the teacher's way | the other way | stands |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [f"| {name} | {behaviour_cells(b)} |" for name, b in table["policies"].items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("policies", type=Path, nargs="*", help="shipped one-network float CNNs (models/policy/NAME)")
    parser.add_argument(
        "--driven", action="store_true", help="read a policy-driven DAgger round's own recorded commands instead of running policies"
    )
    parser.add_argument("--dataset", type=Path, required=True, help="a dribble dataset recorded with ground truth")
    parser.add_argument("--seeds", type=seed_range, required=True, metavar="A..B", help="its episodes to read, A to B - 1")
    parser.add_argument("--json", type=Path, help="the table as JSON too")
    args = parser.parse_args(argv)
    seeds = list(args.seeds)
    if bool(args.policies) == args.driven:
        parser.error("give policies to run, or --driven to read the recorded ones, not both")
    try:
        seed_ranges.refuse_reserved(seeds, "--seeds", use="offline look (it informs choices)")
        data = dataset.load(args.dataset, require_seeds=seeds)
        if args.driven:
            table = driven_study(data.subset(seeds), recorded_policy_commands(args.dataset, seeds))
        else:
            table = study(args.policies, data.subset(seeds))
    except (dataset.DatasetError, ValueError) as error:
        print(f"detour_rows: {error}", file=sys.stderr)
        return 2
    print(driven_markdown(table, seeds, args.dataset) if args.driven else markdown(table, seeds))
    if args.json:
        args.json.write_text(json.dumps({"seeds": seeds, **table}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
