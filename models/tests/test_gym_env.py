"""The Gymnasium environment: Gymnasium's own checker, the episodes of `dribble eval` replayed
through it (bit for bit with the teacher's commands, within the engines' rounding with a
shipped policy through onnxruntime), and its protocol's edges."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from dribble_models import gym_env
from dribble_models.gym_equivalence import (
    OnnxPolicy,
    compare,
    play_in_environment,
    play_in_eval,
)
from test_dataset import REPOSITORY, dribble_binary


@pytest.fixture(autouse=True)
def built_binary(monkeypatch):
    monkeypatch.setenv("DRIBBLE_BIN", str(dribble_binary()))


def test_gymnasium_check_env_passes_on_the_registered_environment():
    env = gym.make(gym_env.ENV_ID, time_limit_s=2.0)
    try:
        with _no_warnings():
            check_env(env.unwrapped)
    finally:
        env.close()


class _no_warnings:
    """Fails on any warning check_env raises (it reports problems as warnings)."""

    def __enter__(self):
        import warnings

        self._catcher = warnings.catch_warnings(record=True)
        self._caught = self._catcher.__enter__()
        warnings.simplefilter("always")

    def __exit__(self, *exc):
        self._catcher.__exit__(*exc)
        messages = [str(w.message) for w in self._caught if "render" not in str(w.message)]
        assert not messages, messages


def test_the_teacher_through_the_environment_replays_dribble_eval_bit_for_bit():
    seeds = [10003]
    teacher = play_in_environment(
        lambda _, info: info["expert_command"].astype(np.float32), seeds, 5.0, "observable"
    )
    evaluation = play_in_eval("expert", seeds, 5.0, "observable")
    (row,) = compare(teacher, evaluation)
    assert row["outcome_env"] == row["outcome_eval"]
    assert row["commands_env"] == row["commands_eval"] == teacher[0].steps
    assert row["robot_gap_m"] == 0.0 and row["ball_gap_m"] == 0.0, row


def test_a_shipped_policy_through_onnxruntime_plays_as_dribble_eval():
    manifest = REPOSITORY / "models/policy/cnn-dagger1-observable/policy.toml"
    policy = OnnxPolicy(manifest)
    seeds = [10000, 10001]
    environment = play_in_environment(lambda observation, _: policy(observation), seeds, 4.0)
    evaluation = play_in_eval(str(manifest), seeds, 4.0)
    for row in compare(environment, evaluation):
        assert row["outcome_env"] == row["outcome_eval"], row
        assert row["commands_env"] == row["commands_eval"], row
        # onnxruntime and the compiled engine round differently; the cameras carry the
        # difference into the next images (DESIGN.md-sized drift: about a millimetre).
        assert row["robot_gap_m"] < 5e-3 and row["ball_gap_m"] < 5e-3, row
    # The robot moved: a policy that stood would pass the comparison trivially.
    assert np.linalg.norm(environment[0].robot[-1] - environment[0].robot[0]) > 0.1


def test_a_policy_reading_its_last_command_plays_as_dribble_eval_feeds_it():
    """The fixture that reads its last command: onnxruntime fed the command this side sent
    last (zero at the start), the controller fed the command it published last; the same
    paths within the engines' rounding, so both sides feed the same last command."""
    manifest = REPOSITORY / "models/fixtures/cnn-previous/policy.toml"
    policy = OnnxPolicy(manifest)
    assert policy.reads_previous
    seeds = [7]
    environment = play_in_environment(policy, seeds, 5.0)
    evaluation = play_in_eval(str(manifest), seeds, 5.0)
    (row,) = compare(environment, evaluation)
    assert row["outcome_env"] == row["outcome_eval"], row
    assert row["commands_env"] == row["commands_eval"], row
    assert row["robot_gap_m"] < 5e-3 and row["ball_gap_m"] < 5e-3, row
    assert np.linalg.norm(environment[0].robot[-1] - environment[0].robot[0]) > 0.02
    # Fed a stop at every step instead, the same network walks elsewhere: the controller's
    # path is the one of a network given its last command.
    at_rest = OnnxPolicy(manifest)

    def forgetting(observation, info):
        at_rest.reset()
        return at_rest(observation)

    (unfed,) = compare(play_in_environment(forgetting, seeds, 5.0), evaluation)
    print(f"gap to the controller's path: fed {row['robot_gap_m']:.4f} m, unfed {unfed['robot_gap_m']:.4f} m")
    assert unfed["robot_gap_m"] > 10 * max(row["robot_gap_m"], 1e-3), (unfed, row)


def test_reset_in_mid_episode_replays_the_episode_and_the_end_is_reported_once():
    env = gym_env.NaoDribbleEnv(time_limit_s=1.0, shaping=1.0)
    try:
        first, info = env.reset(seed=10002)
        assert first["top"].dtype == np.uint8 and first["top"].shape == (120, 160)
        assert info["seed"] == 10002 and info["expert_phase"] in (
            "search", "approach", "align", "dribble"
        )  # fmt: skip
        env.step(np.zeros(3, np.float32))
        again, _ = env.reset(seed=10002)  # abandons the episode under way
        assert np.array_equal(first["top"], again["top"])
        assert np.array_equal(first["bottom"], again["bottom"])
        total, start_distance = 0.0, env._ball_distance
        while True:
            _, reward, terminated, truncated, info = env.step(info["expert_command"])
            total += reward
            if terminated or truncated:
                break
        assert truncated and not terminated and info["outcome"] == "time_limit"
        # Shaping alone: the decrease of the ball's distance to the goal's centre.
        end_distance = np.linalg.norm(info["ball"] - info["goal_centre"])
        assert total == pytest.approx(start_distance - end_distance, abs=1e-9)
        with pytest.raises(RuntimeError, match="reset"):
            env.step(np.zeros(3, np.float32))
        other, _ = env.reset()  # an unnamed seed, drawn from the generator
        assert env.observation_space.contains(other)
    finally:
        env.close()


def test_a_bad_binary_or_teacher_is_refused_with_the_reason(tmp_path):
    with pytest.raises(ValueError, match="observable"):
        gym_env.NaoDribbleEnv(expert="oracle")
    broken = tmp_path / "dribble"
    broken.write_text("#!/bin/sh\necho 'no renderer here' >&2\nexit 3\n")
    broken.chmod(0o755)
    env = gym_env.NaoDribbleEnv(binary=str(broken))
    try:
        with pytest.raises(gym_env.ServerError, match="no renderer here"):
            env.reset(seed=1)
    finally:
        env.close()


def test_the_books_ten_lines_run(tmp_path, capsys):
    readme = (REPOSITORY / "docs" / "src" / "guide" / "gym-ray.md").read_text()
    block = readme.split("<!-- gym example -->\n```python\n", 1)[1].split("```", 1)[0]
    assert "range(10000, 10020)" in block and 'gym.make("dribble/NaoDribble-v0")' in block
    # One short episode instead of twenty whole ones.
    short = block.replace("range(10000, 10020)", "range(10000, 10001)").replace(
        'gym.make("dribble/NaoDribble-v0")', 'gym.make("dribble/NaoDribble-v0", time_limit_s=1.0)'
    )
    namespace: dict = {}
    exec(compile(short, "gym-ray.md", "exec"), namespace)
    namespace["env"].close()
    assert capsys.readouterr().out.strip() == "0 goals of 20"


def test_the_environment_plays_under_a_condition_and_refuses_one_it_cannot_read():
    clean = gym_env.NaoDribbleEnv(time_limit_s=1.0)
    noisy = gym_env.NaoDribbleEnv(time_limit_s=1.0, condition="noise:3")
    one_sample = gym_env.NaoDribbleEnv(time_limit_s=1.0, camera_samples=1)
    try:
        first, _ = clean.reset(seed=20_004)
        seen, _ = noisy.reset(seed=20_004)
        again, _ = noisy.reset(seed=20_004)
        # The same seed under noise: other pixels than clean, the same ones again.
        assert not np.array_equal(first["top"], seen["top"])
        assert np.array_equal(seen["top"], again["top"])
        # One camera sample a pixel: the same scene, a few thumbnail pixels otherwise (edges).
        edges, _ = one_sample.reset(seed=20_004)
        changed = np.abs(edges["top"].astype(int) - first["top"].astype(int)) > 2
        assert 0 < changed.mean() < 0.05
    finally:
        clean.close()
        noisy.close()
        one_sample.close()
    with pytest.raises(ValueError, match="camera_samples"):
        gym_env.NaoDribbleEnv(camera_samples=2)
    broken = gym_env.NaoDribbleEnv(time_limit_s=1.0, condition="fog:3")
    try:
        with pytest.raises(gym_env.ServerError, match="fog"):
            broken.reset(seed=20_004)
    finally:
        broken.close()
