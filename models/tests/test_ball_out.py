"""The ways a ball leaves the field, told apart on paths built for each case."""

import json

from dribble_models import ball_out


def _episode(seed, ball, robot, outcome="ball_out"):
    return {"seed": seed, "outcome": outcome, "ball": ball, "robot": robot, "heading": [0.0] * len(ball)}


def _line(start, end, samples):
    return [[start[0] + (end[0] - start[0]) * i / (samples - 1), start[1] + (end[1] - start[1]) * i / (samples - 1)] for i in range(samples)]


def test_a_ball_pushed_sideways_from_the_goal_side_is_carried_out_while_going_around():
    # Target goal at -4.5 (the ball starts at x < 0); the robot stands on that goal's side of
    # the ball and walks it to the side line: nearly straight away from the goal.
    ball = _line((-2.0, 1.0), (-2.0, 3.1), 40)
    robot = [[x - 0.1, y - 0.1] for x, y in ball]
    row = ball_out.way_out(_episode(20011, ball, robot))
    assert row["line"] == "side" and row["way"] == "carried while going around"
    assert row["contact_s"] == 3.9 and row["off_line_deg"] > 150
    # Pushed from the far side of the ball instead, toward the goal: dribbled wide.
    assert ball_out.way_out(_episode(5, ball, [[x + 0.15, y] for x, y in ball]))["way"] == "dribbled wide"


def test_a_ball_pushed_from_behind_past_the_post_is_dribbled_wide_over_the_target_end():
    ball = _line((3.0, 0.9), (4.6, 0.9), 30)
    robot = [[x - 0.15, y] for x, y in ball]
    row = ball_out.way_out(_episode(1, ball, robot))
    assert (row["line"], row["way"]) == ("target end", "dribbled wide")
    # The same toward the own goal's end: the target goal is the one on the ball's starting side.
    mirrored = ball_out.way_out(_episode(2, [[-x, y] for x, y in ball], [[-x, y] for x, y in robot]))
    assert (mirrored["line"], mirrored["way"]) == ("target end", "dribbled wide")
    own = ball_out.way_out(_episode(3, [[3.0, 0.5]] + _line((3.0, 0.5), (-4.6, 0.5), 30)[1:], [[3.2, 0.5]] * 30))
    assert own["line"] == "own end"


def test_a_ball_untouched_for_a_second_before_it_left_rolled_out():
    ball = _line((2.0, 2.0), (2.0, 3.1), 25)
    robot = [[2.0, 1.8]] * 5 + [[2.0, 1.0]] * 20
    row = ball_out.way_out(_episode(4, ball, robot))
    assert (row["line"], row["way"], row["off_line_deg"]) == ("side", "rolled out", None)


def test_only_balls_out_are_listed_and_the_command_tallies_them(tmp_path, capsys):
    ball = _line((-2.0, 1.0), (-2.0, 3.1), 40)
    carried = _episode(20011, ball, [[x - 0.1, y - 0.1] for x, y in ball])
    goal = _episode(20001, ball, ball, outcome="goal")
    path = tmp_path / "run.json"
    path.write_text(json.dumps({"episodes": [carried, goal]}))
    assert ball_out.main([str(path), "--json", str(tmp_path / "out.json")]) == 0
    assert "1 balls out: carried while going around over the side line 1" in capsys.readouterr().out
    assert json.loads((tmp_path / "out.json").read_text())["tally"] == {"carried while going around / side": 1}
    path.write_text(json.dumps({"episodes": [{"seed": 1, "outcome": "ball_out"}]}))
    assert ball_out.main([str(path)]) == 2
    assert f"error: {path} is not a `dribble eval --trajectories` file with paths" in capsys.readouterr().err
