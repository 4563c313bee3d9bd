"""dribble datasets in LeRobot's format: the rows LeRobot's loader reads back are the rows
written (with LeRobot's own writer and loader, in its environment, where scripts/lerobot has
made one), and a LeRobot export converts back to a dribble dataset with the same rows."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from dribble_models import lerobot_format
from dribble_models.dataset import Episode, load

REPOSITORY = Path(__file__).resolve().parents[2]
LEROBOT_VENV = Path(os.environ.get("DRIBBLE_LEROBOT_VENV", Path.home() / ".cache/dribble/lerobot-venv"))


def episode(seed: int, rows: int) -> Episode:
    random = np.random.default_rng(seed)
    return Episode(
        seed=seed,
        top=random.integers(0, 256, (rows, 120, 160), dtype=np.uint8),
        bottom=random.integers(0, 256, (rows, 60, 80), dtype=np.uint8),
        command=random.uniform(-1, 1, (rows, 3)).astype(np.float32),
        phase=random.integers(0, 4, rows).astype(np.uint8),
        robot_pose=random.normal(size=(rows, 3)).astype(np.float32),
        ball=random.normal(size=(rows, 2)).astype(np.float32),
        time_s=np.arange(rows) / 30.0,
    )


def test_rows_written_back_as_a_dribble_dataset_load_the_same(tmp_path):
    episodes = [(episode(3, 5), {}), (episode(4, 2), {"policy_command": np.zeros((2, 3), np.float32), "expert_executed": np.array([0, 1], np.uint8)})]
    lerobot_format.write_dribble(episodes, tmp_path / "back", teacher="observable")
    back = load(tmp_path / "back")
    assert back.teacher == "observable" and back.seeds() == [3, 4]
    written = [(e, extra) for e, extra in episodes]
    extras = {3: {}, 4: episodes[1][1]}
    read = [(e, extras[e.seed]) for e in back.episodes]
    assert lerobot_format.differences(back, extras, written) == []
    assert lerobot_format.differences(back, extras, read) == []


def test_a_changed_pixel_or_command_is_a_difference(tmp_path):
    original = episode(7, 3)
    source = type("Source", (), {"episodes": [original], "seeds": lambda self: [7]})()
    changed = Episode(**{**original.__dict__, "top": original.top.copy(), "command": original.command.copy()})
    changed.top[1, 2, 3] ^= 1
    changed.command[2, 0] += 1e-6
    found = lerobot_format.differences(source, {}, [(changed, {})])
    assert found == ["episode 7: top differs", "episode 7: command differs"]


@pytest.mark.skipif(not (LEROBOT_VENV / "bin" / "python").exists(), reason="no LeRobot environment (scripts/lerobot makes one)")
def test_lerobot_reads_an_export_as_the_same_rows(tmp_path):
    source = tmp_path / "source"
    lerobot_format.write_dribble([(episode(11, 4), {}), (episode(12, 3), {})], source, teacher="detector")
    run = lambda *args: subprocess.run([str(REPOSITORY / "scripts" / "lerobot"), *args], capture_output=True, text=True)  # noqa: E731
    exported = run("export", str(source), str(tmp_path / "lerobot"))
    assert exported.returncode == 0, exported.stderr
    info = json.loads((tmp_path / "lerobot" / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["total_frames"] == 7 and info["splits"] == {"train": "0:1", "validation": "1:2"}
    checked = run("check", str(source), str(tmp_path / "lerobot"))
    assert checked.returncode == 0, checked.stderr
    assert "the same rows" in checked.stdout
    # A frame as LeRobot's policies get it: the state a vector (a one-value feature comes
    # back as a scalar, which ACT's state projection refuses), the images channels first.
    shapes = subprocess.run(
        [str(LEROBOT_VENV / "bin" / "python"), "-c",
         "import sys; from lerobot.datasets.lerobot_dataset import LeRobotDataset; "
         "f = LeRobotDataset('dribble/test', root=sys.argv[1])[0]; "
         "print(tuple(f['observation.state'].shape), tuple(f['observation.images.top'].shape))",
         str(tmp_path / "lerobot")], capture_output=True, text=True)
    assert shapes.returncode == 0, shapes.stderr
    assert shapes.stdout.split("\n")[-2] == "(2,) (3, 120, 160)"


@pytest.mark.skipif(not (LEROBOT_VENV / "bin" / "python").exists(), reason="no LeRobot environment (scripts/lerobot makes one)")
def test_lerobots_eval_policy_plays_a_dribble_episode_with_a_shipped_cnn(tmp_path):
    """LeRobot's make_env and eval_policy (the `--env.type=dribble` configuration) run the CNN
    fixture through DribbleOnnxPolicy for one short episode; LeRobot's success is dribble's goal."""
    out = tmp_path / "eval.json"
    played = subprocess.run(
        [str(REPOSITORY / "scripts" / "lerobot"), "eval", "--policy", str(REPOSITORY / "models" / "fixtures" / "cnn"),
         "--seeds", "10000..10001", "--time-limit", "2", "--out", str(out)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert played.returncode == 0, played.stderr[-2000:]
    summary = json.loads(out.read_text())
    (episode,) = summary["per_episode"]
    assert episode["seed"] == 10000 and episode["outcome"] in ("goal", "time_limit", "ball_out")
    assert episode["lerobot_success"] == (episode["outcome"] == "goal") == episode["is_success"]
    assert summary["episodes"] == 1 and summary["goals"] == int(episode["outcome"] == "goal")


@pytest.mark.skipif(not (LEROBOT_VENV / "bin" / "python").exists(), reason="no LeRobot environment (scripts/lerobot makes one)")
def test_a_cut_off_lerobot_evaluation_continues_from_its_journal_with_jobs(tmp_path):
    """An episode already in `OUT.partial` is kept, not played again (its made-up goal is
    counted); the rest are played by two jobs; the journal goes once the summary is written;
    a journal of another run (another time limit) is refused."""
    fixture = REPOSITORY / "models" / "fixtures" / "cnn"
    out = tmp_path / "eval.json"
    journal = tmp_path / "eval.json.partial"
    journal.mkdir()
    run = {"policy": str(fixture), "conditions": "clean", "time_limit_s": 2.0, "action_steps": None}
    kept = {"seed": 1, "outcome": "goal", "duration_s": 1.5, "is_success": True, "lerobot_success": True, "wall_s": 0.0}
    (journal / "1.json").write_text(json.dumps({**kept, "run": run}))
    evaluate = lambda limit: subprocess.run(  # noqa: E731
        [str(REPOSITORY / "scripts" / "lerobot"), "eval", "--policy", str(fixture), "--seeds", "1..4",
         "--time-limit", limit, "--jobs", "2", "--out", str(out)],
        capture_output=True, text=True,
    )  # fmt: skip
    played = evaluate("2")
    assert played.returncode == 0, played.stderr[-2000:]
    summary = json.loads(out.read_text())
    assert [e["seed"] for e in summary["per_episode"]] == [1, 2, 3] and summary["per_episode"][0] == kept
    assert summary["jobs"] == 2 and summary["goals"] == 1 + sum(e["outcome"] == "goal" for e in summary["per_episode"][1:])
    assert not journal.exists()
    journal.mkdir()
    (journal / "1.json").write_text(json.dumps({**kept, "run": run}))
    refused = evaluate("3")
    assert refused.returncode == 2 and "another run" in refused.stderr, refused.stderr[-2000:]


TINY_ACT = """
import sys
from pathlib import Path
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.act.configuration_act import ACTConfig
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.factory import make_pre_post_processors
from dribble_models.lerobot_eval import BOTTOM, STATE, TOP

torch.manual_seed(0)
config = ACTConfig(device="cpu", pretrained_backbone_weights=None, dim_model=32, dim_feedforward=64, n_heads=2,
                   n_encoder_layers=1, n_decoder_layers=1, use_vae=False, chunk_size=2, n_action_steps=1)
config.input_features = {TOP: PolicyFeature(FeatureType.VISUAL, (3, 120, 160)),
                         BOTTOM: PolicyFeature(FeatureType.VISUAL, (3, 60, 80)),
                         STATE: PolicyFeature(FeatureType.STATE, (2,))}
config.output_features = {"action": PolicyFeature(FeatureType.ACTION, (3,))}
image = {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.2)}
stats = {TOP: image, BOTTOM: image, STATE: {"mean": torch.zeros(2), "std": torch.ones(2)},
         "action": {"mean": torch.zeros(3), "std": torch.full((3,), 0.5)}}
preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=stats)
out = Path(sys.argv[1])
for part in (ACTPolicy(config), preprocessor, postprocessor):
    part.save_pretrained(out)
"""


@pytest.mark.skipif(not (LEROBOT_VENV / "bin" / "python").exists(), reason="no LeRobot environment (scripts/lerobot makes one)")
def test_lerobots_eval_policy_plays_a_policy_lerobot_saved(tmp_path):
    """A LeRobot ACT checkpoint (tiny, random weights, saved as `lerobot-train` saves one)
    plays a short episode through its own processors, with the zeros state the exports hold."""
    checkpoint = tmp_path / "pretrained_model"
    environment = {**os.environ, "PYTHONPATH": str(REPOSITORY / "models")}
    made = subprocess.run([str(LEROBOT_VENV / "bin" / "python"), "-c", TINY_ACT, str(checkpoint)], capture_output=True, text=True, env=environment)
    assert made.returncode == 0, made.stderr[-2000:]
    out = tmp_path / "eval.json"
    played = subprocess.run(
        [str(REPOSITORY / "scripts" / "lerobot"), "eval", "--policy", str(checkpoint),
         "--seeds", "10000..10001", "--time-limit", "1", "--out", str(out), "--action-steps", "2"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert played.returncode == 0, played.stderr[-2000:]
    summary = json.loads(out.read_text())
    assert summary["path"].endswith("LeRobot act") and summary["action_steps"] == 2
    (episode,) = summary["per_episode"]
    assert episode["seed"] == 10000 and episode["duration_s"] <= 1.0 + 1e-6
    # More commands a run than the chunk holds are refused, naming the chunk.
    refused = subprocess.run(
        [str(REPOSITORY / "scripts" / "lerobot"), "eval", "--policy", str(checkpoint),
         "--seeds", "10000..10001", "--time-limit", "1", "--out", str(tmp_path / "no.json"), "--action-steps", "3"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert refused.returncode == 2 and "chunks of 2 commands" in refused.stderr, refused.stderr[-2000:]


@pytest.mark.skipif(not (LEROBOT_VENV / "bin" / "python").exists(), reason="no LeRobot environment (scripts/lerobot makes one)")
def test_train_act_runs_lerobots_trainer_with_the_backbone_at_the_main_rate(tmp_path):
    """`scripts/lerobot train-act` on a tiny export: LeRobot's trainer accepts every option it
    passes, saves a checkpoint, and the ResNet from random weights learns at the rest's rate,
    not at LeRobot's fine-tuning default (1e-5) for ImageNet weights."""
    source = tmp_path / "source"
    lerobot_format.write_dribble([(episode(21, 6), {}), (episode(22, 4), {})], source, teacher="detector")
    run = lambda *args: subprocess.run([str(REPOSITORY / "scripts" / "lerobot"), *args], capture_output=True, text=True)  # noqa: E731
    exported = run("export", str(source), str(tmp_path / "lerobot"))
    assert exported.returncode == 0, exported.stderr
    out = tmp_path / "act"
    trained = run("train-act", str(tmp_path / "lerobot"), str(out), "--steps=2", "--save_freq=2", "--log_freq=1", "--batch_size=2")
    assert trained.returncode == 0, trained.stdout[-3000:] + trained.stderr[-3000:]
    saved = out / "checkpoints" / "000002" / "pretrained_model"
    config = json.loads((saved / "config.json").read_text())
    assert config["pretrained_backbone_weights"] is None
    assert config["optimizer_lr"] == config["optimizer_lr_backbone"] == 1e-4
    assert (saved / "model.safetensors").is_file() and (tmp_path / "act.log").is_file()


TRAINER_LOG = (
    "INFO 2026-11-30 15:06:38 ot_train.py:332 cfg.steps=20000 (20K)\n"
    "Training:   2%|▎         | 499/20000 [00:03<02:14,  3.44s/step]Training:   2%|▎         | 500/20000 [00:03<02:14,  3.44s/step]"
    "INFO 2026-11-30 15:07:02 ot_train.py:435 step:500 smpl:4K ep:5 epch:0.13 loss:0.717 grdn:102.684 lr:1.0e-05 updt_s:2.194 data_s:0.117\n"
    "Training:   5%|▌         | 1000/20000 [00:05<01:35,  2.52s/step]"
    "INFO 2026-11-30 15:07:23 ot_train.py:435 step:1K smpl:8K ep:10 epch:0.26 loss:0.644 grdn:70.893 lr:1.0e-04 updt_s:2.140 data_s:0.022\n"
    "Training:   5%|▌         | 1050/20000 [00:05<01:35,  2.52s/step]"
    "INFO 2026-11-30 15:07:43 ot_train.py:435 step:1K smpl:8K ep:10 epch:0.27 loss:0.600 grdn:60.0 lr:1.0e-04 updt_s:2.0 data_s:0.02\n"
    # Resumed from the checkpoint of step 1000: the bar counts the 19,000 steps left.
    "INFO 2026-11-30 16:00:00 ot_train.py:332 cfg.steps=20000 (20K)\n"
    "Training:   0%|          | 0/19000 [00:05<01:35,  2.52s/step]"
    "INFO 2026-11-30 16:07:23 ot_train.py:435 step:1K smpl:8K ep:10 epch:0.26 loss:0.641 grdn:70.0 lr:1.0e-04 updt_s:1.9 data_s:0.02\n"
    "Training:   0%|          | 100/19000 [00:05<01:35,  2.52s/step]"
    "INFO 2026-11-30 16:09:23 ot_train.py:435 step:1K smpl:9K ep:11 epch:0.29 loss:0.55 grdn:60.0 lr:1.0e-04 updt_s:1.9 data_s:0.02\n"
    # A log without the progress bar before a line: the line's own (rounded) step.
    "INFO 2026-11-30 16:17:23 ot_train.py:435 step:1.5K smpl:12K ep:15 epch:0.39 loss:0.5 grdn:40.0 lr:1.0e-04 updt_s:1.8 data_s:0.02\n"
)


def test_the_trainers_log_reads_as_steps_and_a_resumed_step_keeps_its_last_line(tmp_path):
    from dribble_models import lerobot_curve

    log = tmp_path / "run.log"
    log.write_text(TRAINER_LOG)
    steps = lerobot_curve.training_log(log)
    assert [s["step"] for s in steps] == [500, 1000, 1050, 1100, 1500]
    assert [s["samples"] for s in steps] == [4000, 8000, 8000, 9000, 12000]
    assert steps[1]["loss"] == 0.641 and steps[2]["loss"] == 0.6 and steps[1]["lr"] == 1e-4 and steps[0]["update_s"] == 2.194


def test_checkpoints_are_the_numbered_ones_with_weights(tmp_path):
    from dribble_models import lerobot_curve

    for name in ("000010", "000002", "last", "000020"):
        (tmp_path / "checkpoints" / name / "pretrained_model").mkdir(parents=True)
    for name in ("000010", "000002", "last"):
        (tmp_path / "checkpoints" / name / "pretrained_model" / "model.safetensors").write_bytes(b"")
    assert [step for step, _ in lerobot_curve.checkpoints(tmp_path)] == [2, 10]


def test_the_constant_command_is_the_median_of_the_training_episodes_only(tmp_path):
    # An export's whole source holds the held-out episodes too: they take no part in the
    # constant command a run is compared with.
    from dribble_models import lerobot_curve

    trained, held_out = episode(1, 5), episode(2, 7)
    trained.command[:] = 0.5
    held_out.command[:] = -0.5
    lerobot_format.write_dribble([(trained, {}), (held_out, {})], tmp_path / "whole", teacher="observable")
    constant = lerobot_curve.constant_error(tmp_path / "whole", [held_out])
    assert constant["command"] == [0.5, 0.5, 0.5]
    with pytest.raises(ValueError, match="besides the held-out"):
        lerobot_curve.constant_error(tmp_path / "whole", [held_out, trained])


SELECT_ACTION_AGREES = """
import sys
from pathlib import Path
import numpy as np
import torch
from dribble_models import lerobot_curve
from dribble_models.dataset import load
from dribble_models.lerobot_eval import policy_and_processors

model, dataset = Path(sys.argv[1]), Path(sys.argv[2])
(episode,) = load(dataset).episodes
batched = lerobot_curve.commands(lerobot_curve.loaded(model), episode)
policy, preprocessor, postprocessor, _ = policy_and_processors(model)
one_by_one = []
with torch.no_grad():
    for row in range(len(episode.command)):
        policy.reset()
        action = policy.select_action(preprocessor(lerobot_curve.batch_of(episode, slice(row, row + 1))))
        one_by_one.append(postprocessor(action).numpy()[0])
difference = float(np.abs(batched - np.array(one_by_one)).max())
print(difference)
assert batched.shape == (len(episode.command), 3) and difference < 1e-5, difference
"""


@pytest.mark.skipif(not (LEROBOT_VENV / "bin" / "python").exists(), reason="no LeRobot environment (scripts/lerobot makes one)")
def test_the_curves_commands_are_what_lerobots_select_action_sends(tmp_path):
    """The validation error of a checkpoint scores the command LeRobot's own `select_action`
    would send on each row (the first of the chunk, through the saved processors), in batches."""
    checkpoint = tmp_path / "run" / "checkpoints" / "000002" / "pretrained_model"
    environment = {**os.environ, "PYTHONPATH": str(REPOSITORY / "models")}
    made = subprocess.run([str(LEROBOT_VENV / "bin" / "python"), "-c", TINY_ACT, str(checkpoint)], capture_output=True, text=True, env=environment)
    assert made.returncode == 0, made.stderr[-2000:]
    lerobot_format.write_dribble([(episode(7, 70), {})], tmp_path / "data", teacher="detector")
    agreed = subprocess.run(
        [str(LEROBOT_VENV / "bin" / "python"), "-c", SELECT_ACTION_AGREES, str(checkpoint), str(tmp_path / "data")],
        capture_output=True, text=True, env=environment,
    )  # fmt: skip
    assert agreed.returncode == 0, agreed.stderr[-2000:]
    lerobot_format.write_dribble([(episode(8, 30), {})], tmp_path / "training", teacher="detector")
    curve = tmp_path / "curve.json"
    scored = subprocess.run(
        [str(REPOSITORY / "scripts" / "lerobot"), "curve", str(tmp_path / "run"), "--dataset", str(tmp_path / "data"),
         "--seeds", "7..8", "--training-dataset", str(tmp_path / "training"), "--out", str(curve)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert scored.returncode == 0, scored.stderr[-2000:]
    summary = json.loads(curve.read_text())
    (point,) = summary["checkpoints"]
    assert point["step"] == 2 and point["rows"] == 70 and 0.0 < point["error"] < 2 * np.sqrt(3)
    assert point["teacher_spread"] == [round(float(v), 4) for v in episode(7, 70).command.std(axis=0)]
    assert len(point["command_spread"]) == 3 and min(point["command_spread"]) >= 0.0
    # One constant command, the training rows' median, scored on the held-out rows.
    rows = episode(7, 70).command
    median = np.median(episode(8, 30).command, axis=0)
    assert summary["constant"]["command"] == [round(float(c), 4) for c in median]
    assert abs(summary["constant"]["error"] - float(np.sqrt(((rows - median) ** 2).sum(axis=1)).mean())) < 1e-6
    assert summary["forward"]["step"] == 2 and summary["forward"]["median_ms"] > 0
