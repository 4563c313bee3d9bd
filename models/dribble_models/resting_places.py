"""Where a policy comes to rest in the episodes it does not score, and which resting places
several episodes share, from the 10 Hz paths and headings that `dribble eval --trajectories`
writes. A study tool for the selection seeds, where failures may be studied.

    python -m dribble_models.resting_places TRAJECTORIES.json [--json OUT.json]

Per episode without a goal that ends at rest (over the last REST_S the robot stayed within
REST_MOVE_M and REST_TURN_RAD of where and how it stood when that stretch began): since when it rests, the pose (field frame:
x m, y m, heading rad), the ball's distance and bearing from there (robot frame, + left), and
when the ball was first sighted (`first_sighting_s`, none where the teacher's sighting rule
never saw it). Then the places where more than one episode came to rest, within
SAME_PLACE_M and SAME_HEADING_RAD of each other: a reactive policy that walks to the same
pose from other starts, with the ball elsewhere each time, rests where its own images hold
it still, a fixed point of what it sees there, not of the episode's state.
"""

from __future__ import annotations

import json
import math
import sys

from .eval_summary import PATH_RATE_HZ, NotPaths, study_of_paths, study_parser, summarise_episode, wrap_angle

#: The stretch at an episode's end over which the robot must have stayed put, seconds.
REST_S = 10.0
#: Moved less than this over that stretch (its farthest from where the stretch began), metres.
REST_MOVE_M = 0.1
#: And faced within this of where it faced when the stretch began, radians (a sum of every
#: step's turn would count the walk's sway on the spot as turning).
REST_TURN_RAD = 0.3
#: Two resting poses closer than these are one place.
SAME_PLACE_M = 0.3
SAME_HEADING_RAD = 0.3


def _at_rest(robot: list, heading: list, start: int) -> bool:
    """Whether the robot stayed put from sample `start` to the end."""
    moved = max(math.dist(robot[start], r) for r in robot[start:])
    turned = max(abs(wrap_angle(h - heading[start])) for h in heading[start:])
    return moved < REST_MOVE_M and turned < REST_TURN_RAD


def resting_place(episode: dict) -> dict | None:
    """Where and since when one episode's robot rests at the end; None where it does not or
    where the episode is shorter than REST_S. Its paths and headings must be present."""
    robot, ball, heading = episode.get("robot"), episode.get("ball"), episode.get("heading")
    if not robot or not ball or not heading or not len(robot) == len(ball) == len(heading):
        raise ValueError(f"seed {episode.get('seed')}: no paths and headings of equal length")
    window = int(REST_S * PATH_RATE_HZ)
    if len(robot) <= window:
        return None
    if not _at_rest(robot, heading, len(robot) - 1 - window):
        return None
    # The earliest sample from which it has stayed put to the end.
    start = len(robot) - 1 - window
    while start > 0 and _at_rest(robot, heading, start - 1):
        start -= 1
    (x, y), theta, (bx, by) = robot[-1], heading[-1], ball[-1]
    return {
        "seed": episode["seed"],
        "class": summarise_episode(episode)["failure_class"],
        "since_s": round(start / PATH_RATE_HZ, 1),
        "pose": [round(x, 2), round(y, 2), round(wrap_angle(theta), 2)],
        "ball_m": round(math.dist((x, y), (bx, by)), 2),
        "ball_bearing_rad": round(wrap_angle(math.atan2(by - y, bx - x) - theta), 2),
        "first_sighting_s": episode.get("first_sighting_s"),
    }


def resting_places(trajectories: dict) -> list[dict]:
    """`resting_place` of every episode without a goal that ends at rest, in seed order."""
    episodes = sorted(trajectories["episodes"], key=lambda e: e["seed"])
    rows = (resting_place(e) for e in episodes if e["outcome"] != "goal")
    return [row for row in rows if row is not None]


def shared_places(rows: list[dict]) -> list[list[int]]:
    """The seeds of each place where more than one episode rests (greedy, in seed order: an
    episode joins the first place whose first pose is within SAME_PLACE_M and
    SAME_HEADING_RAD of its own)."""
    places: list[tuple[list[float], list[int]]] = []
    for row in rows:
        x, y, theta = row["pose"]
        for (px, py, ptheta), seeds in places:
            if math.dist((x, y), (px, py)) < SAME_PLACE_M and abs(wrap_angle(theta - ptheta)) < SAME_HEADING_RAD:
                seeds.append(row["seed"])
                break
        else:
            places.append((row["pose"], [row["seed"]]))
    return [seeds for _, seeds in places if len(seeds) > 1]


def main(argv: list[str] | None = None) -> int:
    args = study_parser("resting_places", __doc__, "also write the rows and the shared places as JSON").parse_args(argv)
    try:
        rows = study_of_paths(args.trajectories, resting_places)
    except NotPaths as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    for row in rows:
        x, y, theta = row["pose"]
        sighted = "ball never sighted" if row["first_sighting_s"] is None else f"ball first sighted at {row['first_sighting_s']:.1f} s"
        print(
            f"{row['seed']}  {row['class'] or '-':<18} at rest from {row['since_s']:5.1f} s at ({x:+.2f}, {y:+.2f}) m facing {theta:+.2f} rad; "
            f"ball {row['ball_m']:.2f} m away at {row['ball_bearing_rad']:+.2f} rad; {sighted}"
        )
    shared = shared_places(rows)
    print(f"{len(rows)} episodes end at rest; places shared by more than one: " + ("; ".join(", ".join(map(str, s)) for s in shared) or "none"))
    if args.json is not None:
        args.json.write_text(json.dumps({"episodes": rows, "shared_places": shared}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
