"""Cutting stalled stretches out of policy-driven rounds (dribble_models.stalls)."""

import numpy as np

from dribble_models import dataset as ds
from dribble_models.stalls import StallRule, cut_all, cut_stalls, stalled_rows

RATE_HZ = 30.0


def episode(poses: np.ndarray, balls: np.ndarray) -> ds.Episode:
    """An episode whose row i is stamped i / 30 s and whose top image holds i."""
    rows = len(poses)
    top = np.zeros((rows, 120, 160), np.uint8)
    top[:, 0, 0] = np.arange(rows) % 256
    return ds.Episode(
        seed=7,
        top=top,
        bottom=np.zeros((rows, 60, 80), np.uint8),
        command=np.zeros((rows, 3), np.float32),
        phase=np.zeros(rows, np.uint8),
        robot_pose=poses.astype(np.float32),
        ball=balls.astype(np.float32),
        time_s=np.arange(rows) / RATE_HZ,
    )


def walking_then_standing_then_walking() -> ds.Episode:
    """2 s walking at 0.2 m/s, 10 s standing, 2 s walking again; the ball lies still."""
    walk, stand = int(2 * RATE_HZ), int(10 * RATE_HZ)
    x = np.concatenate([np.arange(walk) * 0.2 / RATE_HZ, np.full(stand, walk * 0.2 / RATE_HZ), walk * 0.2 / RATE_HZ + np.arange(walk) * 0.2 / RATE_HZ])
    poses = np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1)
    return episode(poses, np.tile([3.0, 1.0], (len(x), 1)))


def test_a_stall_keeps_its_first_seconds_and_loses_the_rest():
    e = walking_then_standing_then_walking()
    stalled = stalled_rows(e, StallRule(after_s=3.0))
    # The first row whose last 3 s all lie within 5 cm of it: 3 s after the walking robot
    # came within 5 cm of where it stands.
    standing_x = e.robot_pose[int(2 * RATE_HZ), 0]
    near = int(np.argmax(standing_x - e.robot_pose[:, 0] < 0.05))
    first_stalled = int(np.argmax(stalled))
    assert abs(first_stalled - (near + 3 * RATE_HZ)) <= 1
    # ...and it lasts until the robot is 5 cm away again.
    away = int(np.argmax(e.robot_pose[:, 0] - standing_x >= 0.05))
    assert stalled[first_stalled:away].all()
    assert not stalled[:first_stalled].any()
    assert not stalled[away:].any()
    pieces = cut_stalls(e, StallRule(after_s=3.0))
    assert len(pieces) == 2
    # The pieces are the kept rows, in order, untouched.
    kept = np.concatenate([p.top[:, 0, 0] for p in pieces])
    assert np.array_equal(kept, e.top[~stalled, 0, 0])
    assert all(p.seed == e.seed for p in pieces)
    assert np.allclose(np.concatenate([p.time_s for p in pieces]), e.time_s[~stalled])


def test_turning_on_the_spot_or_a_rolling_ball_is_no_stall():
    rows = int(10 * RATE_HZ)
    turning = np.stack([np.zeros(rows), np.zeros(rows), np.arange(rows) * 0.5 / RATE_HZ], axis=1)
    still_ball = np.tile([3.0, 1.0], (rows, 1))
    assert not stalled_rows(episode(turning, still_ball), StallRule()).any()
    standing = np.zeros((rows, 3))
    rolling = np.stack([3.0 + np.arange(rows) * 0.1 / RATE_HZ, np.ones(rows)], axis=1)
    assert not stalled_rows(episode(standing, rolling), StallRule()).any()
    # Standing still with the ball still, turning back and forth within the limit: stalled.
    wobble = np.stack([np.zeros(rows), np.zeros(rows), 0.05 * np.sin(np.arange(rows) / 5.0)], axis=1)
    assert stalled_rows(episode(wobble, still_ball), StallRule()).sum() == rows - int(3 * RATE_HZ)


def test_a_heading_across_pi_is_not_a_turn():
    rows = int(6 * RATE_HZ)
    across = np.stack([np.zeros(rows), np.zeros(rows), np.where(np.arange(rows) % 2 == 0, np.pi - 0.01, -np.pi + 0.01)], axis=1)
    assert stalled_rows(episode(across, np.tile([3.0, 1.0], (rows, 1))), StallRule()).any()


def test_episodes_without_poses_are_kept_whole_and_the_report_counts():
    old = ds.Episode(1, np.zeros((90, 120, 160), np.uint8), np.zeros((90, 60, 80), np.uint8), np.zeros((90, 3), np.float32), np.zeros(90, np.uint8))
    pieces, report = cut_all([old, walking_then_standing_then_walking()], StallRule(after_s=3.0))
    assert pieces[0] is old
    assert report.episodes_cut == 1
    assert report.rows_before == 90 + int(14 * RATE_HZ)
    assert report.rows_after == sum(len(p) for p in pieces)
    assert "stalled rows" in report.describe()
