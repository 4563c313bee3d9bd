"""A closed-loop evaluation in a few kilobytes: per episode, how it ended and where the robot
and the ball went, from the 10 Hz paths that `dribble eval --trajectories` writes.

    python -m dribble_models.eval_summary TRAJECTORIES.json SUMMARY.json

The paths (about 1 MB for 20 episodes) stay in the data cache; the summary is what a model
directory keeps and what the results table reads. Per episode: seed, outcome, duration,
commands, failure (if any), metres walked, the share of the episode spent standing, the
closest the robot came to the ball, how far the ball moved toward the target goal (the goal
on the ball's starting side, as the episode protocol sets it) and the ball's distance to
that goal at the end. Beside the episodes: the engine that ran the policy.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

#: Half the SPL field's length, metres: the target goal's x.
GOAL_X_M = 4.5
#: Samples per second in the paths `dribble eval` writes.
PATH_RATE_HZ = 10


def summarise_episode(episode: dict) -> dict:
    robot, ball = episode["robot"], episode["ball"]
    summary = {key: episode[key] for key in ("seed", "outcome", "duration_s", "computed_commands", "failure")}
    if robot and ball:
        goal = (GOAL_X_M * (1.0 if ball[0][0] >= 0 else -1.0), 0.0)
        summary["walked_m"] = round(sum(math.dist(a, b) for a, b in zip(robot, robot[1:])), 3)
        summary["closest_to_ball_m"] = round(min(math.dist(r, b) for r, b in zip(robot, ball)), 3)
        summary["ball_toward_goal_m"] = round(math.dist(ball[0], goal) - math.dist(ball[-1], goal), 3)
        summary["ball_to_goal_end_m"] = round(math.dist(ball[-1], goal), 3)
        # Standing: the robot's position moved less than 5 cm over a second (turning on the
        # spot counts as standing: the paths carry no heading).
        seconds = range(PATH_RATE_HZ, len(robot))
        standing = sum(math.dist(robot[i][:2], robot[i - PATH_RATE_HZ][:2]) < 0.05 for i in seconds)
        summary["standing_share"] = round(standing / len(seconds), 3) if len(seconds) else 0.0
    return summary


def summarise(trajectories: dict) -> dict:
    # The engine that ran the policy ("compiled (avx2+fma)", "tract"): absent from files
    # written before `dribble eval` recorded it, and null for the expert.
    return {
        "engine": trajectories.get("engine"),
        "episodes": [summarise_episode(e) for e in trajectories["episodes"]],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.eval_summary", description=__doc__.split("\n\n")[0])
    parser.add_argument("trajectories", type=Path, help="the file `dribble eval --trajectories` wrote")
    parser.add_argument("summary", type=Path, help="where to write the summary (JSON)")
    args = parser.parse_args(argv)
    try:
        trajectories = json.loads(args.trajectories.read_text())
        summary = summarise(trajectories)
    except (OSError, ValueError, KeyError, TypeError) as error:
        print(f"error: {args.trajectories} is not a `dribble eval --trajectories` file: {error}", file=sys.stderr)
        return 2
    args.summary.write_text(json.dumps(summary, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
