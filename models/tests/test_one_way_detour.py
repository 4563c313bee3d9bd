"""The one-way detour relabelling (dribble_models.one_way_detour)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from dribble_models.dataset import Episode
from dribble_models.one_way_detour import APPROACH, OneWayDetour

RULE = OneWayDetour()


def facing_the_ball_from_its_goal_side() -> tuple[np.ndarray, np.ndarray]:
    """The robot 0.3 m on the -y side of the ball, facing it (+y): a plain sideline ahead."""
    return np.array([0.0, -0.3, math.pi / 2]), np.array([0.0, 0.0])


def test_the_teachers_detour_goes_opposite_ways_for_the_two_goals_and_the_one_way_detour_does_not():
    pose, ball = facing_the_ball_from_its_goal_side()
    plus, detour_plus = RULE.command(pose, ball, 1.0, one_way=False)
    minus, detour_minus = RULE.command(pose, ball, -1.0, one_way=False)
    assert detour_plus and detour_minus
    # The two goals' labels step opposite ways: a CNN that cannot tell them apart learns 0.
    assert plus[1] * minus[1] < 0 and abs(plus[1]) > 0.3 and abs(minus[1]) > 0.3
    one_plus, _ = RULE.command(pose, ball, 1.0, one_way=True)
    one_minus, _ = RULE.command(pose, ball, -1.0, one_way=True)
    np.testing.assert_array_equal(one_plus, one_minus)
    # Clockwise seen from above: facing the ball, the robot steps to its left and turns right
    # to keep the ball ahead.
    assert one_plus[1] > 0.3


def test_away_from_the_ball_the_approach_is_the_teachers():
    pose, ball = np.array([-2.0, 0.0, 0.0]), np.array([0.0, 0.0])
    two_way, detour = RULE.command(pose, ball, 1.0, one_way=False)
    one_way, _ = RULE.command(pose, ball, 1.0, one_way=True)
    assert not detour
    np.testing.assert_array_equal(two_way, one_way)
    assert two_way[0] > 0.5 and abs(two_way[2]) < 1e-6  # straight at the point behind the ball


def episode(commands: np.ndarray, phases: np.ndarray, poses: np.ndarray, balls: np.ndarray) -> Episode:
    n = len(phases)
    return Episode(
        seed=7,
        top=np.zeros((n, 120, 160), np.uint8),
        bottom=np.zeros((n, 60, 80), np.uint8),
        command=commands.astype(np.float32),
        phase=phases.astype(np.uint8),
        robot_pose=poses.astype(np.float32),
        ball=balls.astype(np.float32),
    )


def test_only_rows_the_teachers_detour_reproduces_are_relabelled():
    pose, ball = facing_the_ball_from_its_goal_side()
    ball = ball + np.array([0.5, 0.0])  # the ball's half is +x: the first row says so
    pose = pose + np.array([0.5, 0.0, 0.0])
    teachers, _ = RULE.command(pose, ball, 1.0, one_way=False)
    far = np.array([-1.0, 0.0, 0.0])
    commands = np.array([teachers, teachers, teachers + 0.2, RULE.command(far, ball, 1.0, False)[0]])
    phases = np.array([APPROACH, 2, APPROACH, APPROACH])  # row 1 aligns, row 2 is not the teacher's
    poses = np.array([pose, pose, pose, far])
    balls = np.array([ball] * 4)
    relabelled, mask = RULE.relabelled([episode(commands, phases, poses, balls)])
    assert mask.tolist() == [True, False, False, False]
    got = relabelled[0].command
    np.testing.assert_allclose(got[0], RULE.command(pose, ball, 1.0, one_way=True)[0], atol=1e-6)
    np.testing.assert_array_equal(got[1:], commands[1:].astype(np.float32))


def test_an_episode_without_ground_truth_is_refused():
    e = episode(np.zeros((1, 3)), np.array([APPROACH]), np.zeros((1, 3)), np.zeros((1, 2)))
    e.robot_pose = None
    with pytest.raises(ValueError, match="no ground truth"):
        RULE.relabelled([e])


def test_the_teachers_approach_is_recomputed_as_the_committed_fixture_says():
    """The file sim-harness/src/expert.rs's test checks the teacher against."""
    fixture = json.loads((Path(__file__).resolve().parents[1] / "fixtures" / "teacher-approach.json").read_text())
    assert len(fixture["rows"]) > 100
    assert 0 < sum(r["detour"] for r in fixture["rows"]) < len(fixture["rows"])
    for row in fixture["rows"]:
        command, detour = RULE.command(np.array(row["robot"], float), np.array(row["ball"], float), row["target_side"], one_way=False)
        assert detour == row["detour"]
        np.testing.assert_allclose(command, row["command"], atol=1e-5)
        one_way, _ = RULE.command(np.array(row["robot"], float), np.array(row["ball"], float), row["target_side"], one_way=True)
        np.testing.assert_allclose(one_way, row["one_way_command"], atol=1e-5)
