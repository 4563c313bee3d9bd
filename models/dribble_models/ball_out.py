"""How each ball of a closed-loop run left the field: which line it crossed and what the
robot was doing with it, from the 10 Hz paths and headings that `dribble eval --trajectories`
writes. A study tool for the selection seeds, where failures may be studied.

    python -m dribble_models.ball_out TRAJECTORIES.json [--json OUT.json]

Per ball-out episode: the line (`target end`: the target goal's end line, wide of the posts;
`own end`; `side`), and the way out:
- `carried while going around`: the robot had the ball at its feet (within REACHED_M) when it
  left, and over the last CARRY_WINDOW_S of that contact it pushed it away from the target
  goal (its push more than TOWARD_GOAL_DEG off the line from the ball to the goal): it walked
  the ball along where it had to circle it to get behind it;
- `dribbled wide`: at its feet and pushed with some of its push toward the goal (within
  TOWARD_GOAL_DEG), and yet out, past a post or over a side line;
- `rolled out`: the robot had not touched it in the last ROLLED_S.
Then a tally. The target goal is the one on the ball's starting side (eval_summary's rule).
"""

from __future__ import annotations

import json
import math
import sys
from collections import Counter

from .eval_summary import GOAL_X_M, PATH_RATE_HZ, REACHED_M, NotPaths, study_of_paths, study_parser, wrap_angle

#: How far off the ball-to-goal line, degrees, a push may point and still push toward the goal.
TOWARD_GOAL_DEG = 90.0
#: The stretch of contact before the ball left that decides carried or dribbled, seconds.
CARRY_WINDOW_S = 2.0
#: Without contact for this long before it left, the ball rolled out, seconds.
ROLLED_S = 1.0
#: Half the field's width, metres, and the ball's radius: the lines the ball crosses.
HALF_WIDTH_M = 3.0
BALL_RADIUS_M = 0.05


def way_out(episode: dict) -> dict:
    """The line and the way out of one ball-out episode (its paths must be present)."""
    ball, robot = episode["ball"], episode["robot"]
    if not ball or len(ball) != len(robot):
        raise ValueError(f"seed {episode.get('seed')}: no paths of equal length")
    goal_x = GOAL_X_M * (1.0 if ball[0][0] >= 0 else -1.0)
    x, y = ball[-1]
    if abs(x) > GOAL_X_M + BALL_RADIUS_M:
        line = "target end" if x * goal_x > 0 else "own end"
    else:
        line = "side"
    touching = [i for i, (b, r) in enumerate(zip(ball, robot)) if math.dist(b, r) < REACHED_M]
    last = touching[-1] if touching else None
    if last is None or (len(ball) - 1 - last) / PATH_RATE_HZ > ROLLED_S:
        return {"seed": episode["seed"], "line": line, "way": "rolled out", "contact_s": 0.0, "off_line_deg": None}
    first = last
    while first > 0 and math.dist(ball[first - 1], robot[first - 1]) < REACHED_M:
        first -= 1
    window = range(max(first, last - int(CARRY_WINDOW_S * PATH_RATE_HZ)), last + 1)
    off = []
    for i in window:
        robot_to_ball = math.atan2(ball[i][1] - robot[i][1], ball[i][0] - robot[i][0])
        ball_to_goal = math.atan2(-ball[i][1], goal_x - ball[i][0])
        off.append(abs(math.degrees(wrap_angle(robot_to_ball - ball_to_goal))))
    off_line = sum(off) / len(off)
    way = "dribbled wide" if off_line <= TOWARD_GOAL_DEG else "carried while going around"
    return {
        "seed": episode["seed"],
        "line": line,
        "way": way,
        "contact_s": round((last - first) / PATH_RATE_HZ, 1),
        "off_line_deg": round(off_line, 1),
    }


def ways_out(trajectories: dict) -> list[dict]:
    """`way_out` of every ball-out episode of a `dribble eval --trajectories` file, seed order."""
    return [way_out(e) for e in sorted(trajectories["episodes"], key=lambda e: e["seed"]) if e["outcome"] == "ball_out"]


def main(argv: list[str] | None = None) -> int:
    args = study_parser("ball_out", __doc__, "also write the rows and the tally as JSON").parse_args(argv)
    try:
        rows = study_of_paths(args.trajectories, ways_out)
    except NotPaths as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    for row in rows:
        off = "" if row["off_line_deg"] is None else f", {row['off_line_deg']:.0f} deg off the ball-to-goal line"
        print(f"{row['seed']}  {row['line']:<10}  {row['way']:<27} contact {row['contact_s']:.1f} s{off}")
    tally = Counter((row["way"], row["line"]) for row in rows)
    print(f"{len(rows)} balls out: " + ", ".join(f"{way} over the {line} line {n}" for (way, line), n in sorted(tally.items())))
    if args.json is not None:
        args.json.write_text(json.dumps({"episodes": rows, "tally": {f"{w} / {l}": n for (w, l), n in sorted(tally.items())}}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
