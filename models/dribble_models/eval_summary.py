"""A closed-loop evaluation in a few kilobytes: per episode, how it ended and where the robot
and the ball went, from the 10 Hz paths that `dribble eval --trajectories` writes.

    python -m dribble_models.eval_summary TRAJECTORIES.json SUMMARY.json

The paths (about 1 MB for 20 episodes) stay in the data cache; the summary is what a model
directory keeps and what the results table reads. Per episode: seed, outcome, duration,
commands, failure (if any), metres walked, the share of the episode spent standing, the
closest the robot came to the ball, how far the ball moved toward the target goal (the goal
on the ball's starting side, as the episode protocol sets it) and the ball's distance to
that goal at the end, how far it turned, when it first saw the ball, and for an episode
without a goal its failure class (FAILURE_CLASSES). Beside the episodes: the engine that
ran the policy.

`dribble_models.summary_join` puts such summaries of one run on disjoint seeds together.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from .cluster import seed_range

T = TypeVar("T")

#: Half the SPL field's length, metres: the target goal's x.
GOAL_X_M = 4.5
#: Samples per second in the paths `dribble eval` writes.
PATH_RATE_HZ = 10
#: Within this of the ball, metres, the robot has reached it.
REACHED_M = 0.3
#: Getting this far from the start without reaching the ball is walking off, metres (the
#: farthest point, not the path's length: a standing robot's sway adds up to metres of path).
WALKED_OFF_M = 1.0
#: A robot that reached the ball and stood this share of the episode stood at the ball.
STOOD_AT_THE_BALL_SHARE = 0.5
#: Turning this far in all without walking off is turning in place, radians.
TURNED_IN_PLACE_RAD = math.pi

#: Why an episode ended without a goal, from its paths:
FAILURE_CLASSES = {
    "ball_out": "the ball left the field",
    "controller_lost": "the controller died or stopped answering",
    "stood_at_the_ball": "reached the ball (within 0.3 m), then no goal: stood (under 5 cm a second) half the episode or more",
    "lost_the_ball": "reached the ball (within 0.3 m), then no goal in time, moving most of it",
    "walked_off": "never reached the ball, went 1 m or more from where it started",
    "turned_in_place": "never reached the ball, stayed within 1 m of its start, turned half a turn or more",
    "stood": "never reached the ball, stayed within 1 m of its start, turned less than half a turn",
    "stood_or_turned": "never reached the ball, stayed within 1 m of its start (an older file: no heading)",
}


def wrap_angle(angle: float) -> float:
    """`angle` in radians wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def turned_rad(heading: list[float]) -> float:
    """How far the robot turned in all, either way (each step's change wrapped to ±pi)."""
    return sum(abs(wrap_angle(b - a)) for a, b in zip(heading, heading[1:]))


def failure_class(summary: dict) -> str | None:
    """The class of an episode without a goal (None for a goal)."""
    outcome = summary["outcome"]
    if outcome == "goal":
        return None
    if outcome in ("ball_out", "controller_lost"):
        return outcome
    if summary.get("closest_to_ball_m", math.inf) <= REACHED_M:
        # Standing beside the ball is its own failure (a reactive policy that cannot tell
        # which goal is its target there); a file without the standing share cannot tell.
        return "stood_at_the_ball" if summary.get("standing_share", 0.0) >= STOOD_AT_THE_BALL_SHARE else "lost_the_ball"
    if summary.get("farthest_from_start_m", 0.0) >= WALKED_OFF_M:
        return "walked_off"
    if summary.get("turned_rad") is None:
        return "stood_or_turned"
    return "turned_in_place" if summary["turned_rad"] >= TURNED_IN_PLACE_RAD else "stood"


def class_of(summary: dict) -> str | None:
    """An episode summary's failure class by today's rule where it holds the paths' figures
    (a summary written before a class was added is read by the new rule), else the class
    it was written with, else its outcome."""
    if summary["outcome"] == "goal":
        return None
    if "closest_to_ball_m" in summary and "farthest_from_start_m" in summary:
        return failure_class(summary)
    return summary.get("failure_class") or summary["outcome"]


def summarise_episode(episode: dict) -> dict:
    robot, ball = episode["robot"], episode["ball"]
    summary = {key: episode[key] for key in ("seed", "outcome", "duration_s", "computed_commands", "failure")}
    if robot and ball:
        goal = (GOAL_X_M * (1.0 if ball[0][0] >= 0 else -1.0), 0.0)
        summary["walked_m"] = round(sum(math.dist(a, b) for a, b in zip(robot, robot[1:])), 3)
        summary["farthest_from_start_m"] = round(max(math.dist(robot[0], r) for r in robot), 3)
        summary["closest_to_ball_m"] = round(min(math.dist(r, b) for r, b in zip(robot, ball)), 3)
        summary["ball_toward_goal_m"] = round(math.dist(ball[0], goal) - math.dist(ball[-1], goal), 3)
        summary["ball_to_goal_end_m"] = round(math.dist(ball[-1], goal), 3)
        # Standing: the robot's position moved less than 5 cm over a second (turning on the
        # spot counts as standing: the paths carry no heading).
        seconds = range(PATH_RATE_HZ, len(robot))
        standing = sum(math.dist(robot[i][:2], robot[i - PATH_RATE_HZ][:2]) < 0.05 for i in seconds)
        summary["standing_share"] = round(standing / len(seconds), 3) if len(seconds) else 0.0
    heading = episode.get("heading") or []
    summary["turned_rad"] = round(turned_rad(heading), 3) if heading else None
    summary["first_sighting_s"] = episode.get("first_sighting_s")
    summary["failure_class"] = failure_class(summary)
    if episode.get("drawn_conditions"):
        # A randomized run: what this episode drew from its seed.
        summary["drawn_conditions"] = episode["drawn_conditions"]
    return summary


class LostController(ValueError):
    """Episodes whose controller died or stopped answering: they say nothing of the policy
    (a machine starved by other work trips the lock-step timeout), so no summary counts them."""


class NotPaths(ValueError):
    """A file a study of paths cannot read: not a `dribble eval --trajectories` file, or one
    without the paths and headings the study reads."""


def study_parser(prog: str, doc: str, json_help: str) -> argparse.ArgumentParser:
    """The command line every study of one trajectories file takes (`ball_out`,
    `resting_places`): the file, and `--json OUT` for the rows as JSON."""
    parser = argparse.ArgumentParser(prog=f"python -m dribble_models.{prog}", description=doc.split("\n\n")[0])
    parser.add_argument("trajectories", type=Path, help="the file `dribble eval --trajectories` wrote")
    parser.add_argument("--json", type=Path, metavar="OUT", help=json_help)
    return parser


def study_of_paths(path: Path, study: Callable[[dict], T]) -> T:
    """`study` of the trajectories file at `path`; `NotPaths`, naming the file, where it cannot
    be read or lacks what the study reads."""
    try:
        return study(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError, TypeError, IndexError) as error:
        raise NotPaths(f"{path} is not a `dribble eval --trajectories` file with paths: {error}") from error


def summarise(trajectories: dict, seeds: range | None = None) -> dict:
    """The summary of every episode, or of those whose seed is in `seeds` (a paired look at
    the first seeds of a longer run); a seed of `seeds` the file lacks is an error, and so is
    an episode whose controller was lost (`LostController`)."""
    # The engine that ran the policy ("compiled (avx2+fma)", "tract"): absent from files
    # written before `dribble eval` recorded it, and null for the expert.
    # The conditions the episodes were seen under (`dribble eval --condition`): absent when
    # clean, and in files written before there were conditions.
    episodes = trajectories["episodes"]
    if seeds is not None:
        episodes = [e for e in episodes if e["seed"] in seeds]
        missing = sorted(set(seeds) - {e["seed"] for e in episodes})
        if missing:
            raise ValueError(f"the file holds no episode of the seeds {missing[:5]}")
    lost = [e["seed"] for e in episodes if e["outcome"] == "controller_lost"]
    if lost:
        raise LostController(
            f"seeds {', '.join(map(str, lost))} lost their controller, which says nothing of the policy: "
            "play them again (`dribble eval --resume` does while the run's journal is there; "
            "else move the file aside and run again)"
        )
    summary = {
        "engine": trajectories.get("engine"),
        "episodes": [summarise_episode(e) for e in episodes],
    }
    if trajectories.get("conditions"):
        summary["conditions"] = trajectories["conditions"]
    # Samples a pixel of the cameras' images (`dribble eval --camera-samples`): absent when 4,
    # the frames every shipped result saw.
    if trajectories.get("camera_samples", 4) != 4:
        summary["camera_samples"] = trajectories["camera_samples"]
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.eval_summary", description=__doc__.split("\n\n")[0])
    parser.add_argument("trajectories", type=Path, help="the file `dribble eval --trajectories` wrote")
    parser.add_argument("summary", type=Path, help="where to write the summary (JSON)")
    parser.add_argument("--seeds", type=seed_range, metavar="A..B", help="only the episodes of these seeds (every one of them must be in the file)")
    args = parser.parse_args(argv)
    try:
        trajectories = json.loads(args.trajectories.read_text())
        summary = summarise(trajectories, args.seeds)
    except LostController as error:
        print(f"error: {args.trajectories}: {error}", file=sys.stderr)
        return 3
    except (OSError, ValueError, KeyError, TypeError) as error:
        print(f"error: {args.trajectories} is not a `dribble eval --trajectories` file: {error}", file=sys.stderr)
        return 2
    args.summary.write_text(json.dumps(summary, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
