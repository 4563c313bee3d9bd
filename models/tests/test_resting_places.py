"""Where episodes come to rest, and the places several share, on paths built for each case."""

import json

from dribble_models import resting_places


def _episode(seed, robot, heading, ball, outcome="time_limit", sighted=None):
    return {
        "seed": seed, "outcome": outcome, "duration_s": 90.0, "computed_commands": 2700, "failure": None,
        "robot": robot, "heading": heading, "ball": ball, "first_sighting_s": sighted,
    }


def _walk_then_stand(start, rest, walk_samples, stand_samples):
    walk = [[start[0] + (rest[0] - start[0]) * i / walk_samples, start[1] + (rest[1] - start[1]) * i / walk_samples] for i in range(walk_samples)]
    return walk + [list(rest)] * stand_samples


def test_an_episode_that_walks_then_stands_rests_from_when_it_stopped():
    robot = _walk_then_stand((1.0, -1.0), (-0.6, 0.0), 200, 700)
    heading = [1.9] * len(robot)
    row = resting_places.resting_place(_episode(20008, robot, heading, [[-2.4, -1.1]] * len(robot)))
    # It comes within 0.1 m of where it stops a few samples before it stops.
    assert 19.0 <= row["since_s"] < 20.0 and row["pose"] == [-0.6, 0.0, 1.9] and row["first_sighting_s"] is None
    assert row["ball_m"] == 2.11 and row["class"] == "walked_off"
    # The ball behind it on its left: bearing about +1.8 rad.
    assert 1.7 < row["ball_bearing_rad"] < 1.9


def test_an_episode_still_moving_or_turning_at_the_end_is_not_at_rest():
    moving = _walk_then_stand((1.0, -1.0), (-0.6, 0.0), 850, 50)
    assert resting_places.resting_place(_episode(1, moving, [0.0] * len(moving), [[3.0, 0.0]] * len(moving))) is None
    standing = [[0.0, 0.0]] * 900
    turning = [i * 0.05 for i in range(900)]
    assert resting_places.resting_place(_episode(2, standing, turning, [[3.0, 0.0]] * 900)) is None
    # Swaying on the spot (heading back and forth by 0.05 rad) is rest.
    sway = [0.05 * (i % 2) for i in range(900)]
    assert resting_places.resting_place(_episode(3, standing, sway, [[3.0, 0.0]] * 900))["since_s"] == 0.0


def test_episodes_resting_at_one_pose_share_a_place_and_goals_are_left_out(tmp_path, capsys):
    a = _walk_then_stand((1.0, -1.0), (-0.6, 0.0), 200, 700)
    b = _walk_then_stand((0.3, -1.2), (-0.62, 0.05), 120, 780)
    c = _walk_then_stand((2.0, 2.0), (3.0, 2.0), 100, 800)
    episodes = [
        _episode(20041, b, [1.92] * 900, [[-2.2, -1.6]] * 900),
        _episode(20008, a, [1.89] * 900, [[-2.4, -1.1]] * 900),
        _episode(20010, c, [1.9] * 900, [[-2.4, -1.1]] * 900),
        _episode(20011, a, [-1.2] * 900, [[-2.4, -1.1]] * 900),
        _episode(20001, a, [1.9] * 900, [[-4.6, 0.0]] * 900, outcome="goal"),
    ]
    rows = resting_places.resting_places({"episodes": episodes})
    assert [r["seed"] for r in rows] == [20008, 20010, 20011, 20041]
    # 20011 rests where 20008 does, facing elsewhere: another place.
    assert resting_places.shared_places(rows) == [[20008, 20041]]
    path = tmp_path / "run.json"
    path.write_text(json.dumps({"episodes": episodes}))
    assert resting_places.main([str(path), "--json", str(tmp_path / "out.json")]) == 0
    assert "4 episodes end at rest; places shared by more than one: 20008, 20041" in capsys.readouterr().out
    assert json.loads((tmp_path / "out.json").read_text())["shared_places"] == [[20008, 20041]]
    path.write_text(json.dumps({"episodes": [{"seed": 1, "outcome": "time_limit", "robot": [[0.0]]}]}))
    assert resting_places.main([str(path)]) == 2
    assert f"error: {path} is not a `dribble eval --trajectories` file with paths" in capsys.readouterr().err
