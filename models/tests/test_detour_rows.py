"""The offline look at the teacher's detour rows (dribble_models.detour_rows)."""

import math

import numpy as np
import pytest

from dribble_models import detour_rows
from dribble_models.dataset import Episode
from dribble_models.one_way_detour import APPROACH, OneWayDetour


def episode_at(poses: np.ndarray, ball: np.ndarray, seed: int = 54) -> Episode:
    """An approach episode whose commands are the teacher's two-way approach at each pose."""
    rule = OneWayDetour()
    commands = np.array([rule.command(p, ball, 1.0, one_way=False)[0] for p in poses], np.float32)
    n = len(poses)
    return Episode(
        seed=seed,
        top=np.zeros((n, 120, 160), np.uint8),
        bottom=np.zeros((n, 60, 80), np.uint8),
        command=commands,
        phase=np.full(n, APPROACH, np.uint8),
        robot_pose=poses.astype(np.float32),
        ball=np.tile(ball.astype(np.float32), (n, 1)),
    )


def test_the_goal_bearing_is_measured_from_the_robots_heading():
    # The robot at the centre spot facing +x: the +x goal dead ahead; facing +y: 90 degrees right.
    ball = np.array([0.5, 0.0])
    poses = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, math.pi / 2]])
    bearings = detour_rows.goal_bearings(episode_at(poses, ball), np.arange(2))
    assert bearings == pytest.approx([0.0, -math.pi / 2], abs=1e-6)


def test_only_detour_rows_with_the_goal_out_of_view_are_kept():
    ball = np.array([1.0, 0.0])
    poses = np.array([
        [1.0, -0.3, math.pi / 2],  # beside the ball facing a sideline: a detour, the goal out of view
        [1.6, 0.0, math.pi],  # on the ball's goal side facing it: a detour, the goal behind
        [-2.0, 0.0, 0.0],  # far behind the ball: no detour
    ])
    (_, rows), = detour_rows.aliased_rows([episode_at(poses, ball)])
    assert list(rows) == [0, 1]


def test_sideways_figures_count_steps_each_way_and_stands():
    teacher = np.array([[0.0, 0.6, 0.2], [0.0, -0.6, 0.2], [0.0, 0.6, 0.0], [0.0, 0.5, 0.0]], np.float32)
    sent = np.array([[0.0, 0.5, 0.2], [0.0, 0.4, 0.2], [0.0, 0.0, 0.0], [0.1, 0.1, 0.3]], np.float32)
    b = detour_rows.behaviour(sent, teacher)
    assert b["teachers_way"] == 0.25 and b["other_way"] == 0.25 and b["stands"] == 0.25
    assert b["sideways_size"] == pytest.approx(0.25)
    assert b["teacher_sideways_size"] == pytest.approx(0.575)


def test_reserved_seeds_are_refused(tmp_path, capsys):
    assert detour_rows.main(["--dataset", str(tmp_path), "--seeds", "20000..20002", "models/policy/cnn"]) == 2
    assert "20000" in capsys.readouterr().err


def test_stall_frames_shows_each_hypothesis_and_the_teachers_two_detours(tmp_path, rng):
    """`stall_frames` runs a one-output and a two-hypothesis CNN on a window's thumbnails and
    puts the teacher's detour for either goal beside them."""
    import torch

    from dribble_models import stall_frames
    from dribble_models.export import export_policy
    from dribble_models.manifest import TrainingRecord
    from dribble_models.networks import CNN, ModalCNN

    torch.manual_seed(3)
    export_policy(CNN().eval(), tmp_path / "one", TrainingRecord(dataset="test", epochs=0))
    export_policy(ModalCNN(2).eval(), tmp_path / "two", TrainingRecord(dataset="test", epochs=0))
    window = stall_frames.Window(
        seed=20016,
        top=rng.integers(0, 256, (4, 120, 160), dtype=np.uint8),
        bottom=rng.integers(0, 256, (4, 60, 80), dtype=np.uint8),
        robot_pose=np.array([1.0, -0.3, math.pi / 2]),
        ball=np.array([1.0, 0.0]),
        first_ball=np.array([1.0, 0.0]),
    )
    target, other, detour = stall_frames.teacher_commands(window)
    assert detour and target[1] * other[1] < 0  # beside the ball the two goals' detours step opposite ways
    two = stall_frames.answers(tmp_path / "two", window)
    assert len(two["hypotheses"]) == 2 and sum(share for _, share in two["hypotheses"]) == pytest.approx(1.0)
    text = stall_frames.report(window, [tmp_path / "one", tmp_path / "two"])
    assert "seed 20016, 4 frames" in text and "hypothesis 1:" in text and text.count("sends") == 2


def test_the_driving_policys_recorded_commands_are_weighed_at_the_ball_apart():
    ball = np.array([1.0, 0.0])
    poses = np.array([
        [1.0, -0.25, math.pi / 2],  # a detour row at the ball (0.25 m)
        [1.05, -0.5, math.pi / 2],  # a detour row half a metre from it
        [-2.0, 0.0, 0.0],  # no detour
    ])
    episode = episode_at(poses, ball)
    # The policy walked forward into the ball at the ball and did the teacher's command away from it.
    driven = episode.command.copy()
    driven[0] = [0.8, 0.0, 0.0]
    table = detour_rows.driven_study([episode], {episode.seed: driven})
    assert table["rows"] == 2
    at_ball = table["groups"][f"at the ball (within {detour_rows.AT_BALL_M} m)"]
    assert at_ball["rows"] == 1 and at_ball["forward"] == pytest.approx(0.8)
    assert at_ball["teacher_forward"] == pytest.approx(float(episode.command[0, 0]))
    every = table["groups"]["every detour row"]
    assert every["rows"] == 2 and every["error"] == pytest.approx(at_ball["error"] / 2)


def test_driven_reads_only_a_policy_driven_recording(tmp_path, rng, capsys):
    from test_train import write_dataset

    teacher_driven = write_dataset(tmp_path / "demo", [54, 55], 4, rng)
    assert detour_rows.main(["--driven", "--dataset", str(teacher_driven), "--seeds", "54..56"]) == 2
    assert "policy_command" in capsys.readouterr().err
    driven = write_dataset(tmp_path / "round", [54, 55], 4, rng, driven=True)
    assert detour_rows.main(["--driven", "--dataset", str(driven), "--seeds", "54..56"]) == 0
    with pytest.raises(SystemExit):
        detour_rows.main(["--driven", "--dataset", str(driven), "--seeds", "54..56", "models/policy/cnn"])


def test_stall_frames_feeds_a_narrow_cnn_that_reads_its_last_command_the_one_sent_before_each_frame(tmp_path, rng):
    import torch

    from dribble_models import stall_frames
    from dribble_models.export import export_policy
    from dribble_models.manifest import TrainingRecord
    from dribble_models.networks import CameraFeatures, Filters, PreviousCommandCNN

    # Commands at 100 Hz around frames at 30 Hz (nanoseconds): before the first, none.
    commands = [(t, np.array([t / 1e9, 0.0, -t / 1e9], np.float32)) for t in range(10_000_000, 200_000_000, 10_000_000)]
    previous, sent = stall_frames.commands_around([5_000_000, 40_000_000, 73_333_333, 250_000_000], commands)
    assert previous[:, 0] == pytest.approx([0.0, 0.03, 0.07, 0.19])
    assert sent[:, 0] == pytest.approx([0.01, 0.04, 0.08, 0.19])
    assert stall_frames.commands_around([1], []) == (None, None)

    torch.manual_seed(5)
    network = PreviousCommandCNN(CameraFeatures(Filters(4, 16, 4, 8))).eval()
    with torch.no_grad():
        network.hidden.weight[:, -3:] *= 50.0  # the last command weighs
    export_policy(network, tmp_path / "narrow", TrainingRecord(dataset="test", epochs=0))
    window = stall_frames.Window(
        seed=20008,
        top=rng.integers(0, 256, (2, 120, 160), dtype=np.uint8),
        bottom=rng.integers(0, 256, (2, 60, 80), dtype=np.uint8),
        robot_pose=np.array([-0.6, 0.0, 1.9]),
        ball=np.array([-2.4, -1.1]),
        first_ball=np.array([-2.4, -1.1]),
        previous=np.zeros((2, 3), np.float32),
        sent=np.zeros((2, 3), np.float32),
    )
    standing = stall_frames.answers(tmp_path / "narrow", window)["mean"]
    window.previous = np.tile(stall_frames.previous_command("0,0,1"), (2, 1))
    turning = stall_frames.answers(tmp_path / "narrow", window)["mean"]
    assert not np.allclose(standing, turning, atol=1e-3)
    assert "the driving policy sent (+0.00, +0.00, +0.00)" in stall_frames.report(window, [tmp_path / "narrow"])
    window.previous = None
    with pytest.raises(stall_frames.StallFramesError, match="reads the last command"):
        stall_frames.answers(tmp_path / "narrow", window)
    with pytest.raises(Exception):
        stall_frames.previous_command("0,0,2")
