"""The previous-command study: the network begins as its start, the last command of a
teacher-driven row is the row before's label as sent, reserved seeds never train it.
No test here asserts how well anything learns."""

import json

import numpy as np
import torch

from dribble_models import previous_command as pc
from dribble_models.networks import CNN

from test_train import write_dataset


def test_the_network_begins_as_its_start_whatever_the_last_command():
    cnn = CNN()
    model = pc.PreviousCommandCNN.from_cnn(cnn)
    top, bottom = torch.rand(4, 1, 120, 160), torch.rand(4, 1, 60, 80)
    for previous in (torch.zeros(4, 3), torch.rand(4, 3) * 2 - 1):
        assert torch.allclose(model(top, bottom, previous), cnn(top, bottom), atol=1e-6)
    # The last command is an input: once its weights are not zero, it moves the answer.
    with torch.no_grad():
        model.hidden.weight[:, -3:] = 1.0
    assert not torch.allclose(model(top, bottom, torch.ones(4, 3)), cnn(top, bottom), atol=1e-3)


def test_the_last_command_is_the_row_befores_as_the_controller_sends_it():
    commands = np.array([[0.5, 0.0, 0.0], [1.5, -0.2, np.nan], [0.1, 0.2, 0.3]], np.float32)
    previous = pc.previous_commands(commands)
    assert np.array_equal(previous[0], [0.0, 0.0, 0.0])
    assert np.array_equal(previous[1], [0.5, 0.0, 0.0])
    assert np.array_equal(previous[2], [0.0, 0.0, 0.0])  # a non-finite command was a stop


def test_a_run_trains_refuses_reserved_seeds_and_keeps_its_record(tmp_path, rng, monkeypatch):
    start = CNN()
    monkeypatch.setattr(pc, "start_model", lambda path: start.eval())
    data = write_dataset(tmp_path / "data", [1, 2, 3, 4], 8, rng)
    out = tmp_path / "run.pt"
    common = ["train", "--start", "models/policy/x", "--out", str(out), "--epochs", "2", "--validation-episodes", "1"]
    assert pc.main([*common, "--dataset", str(data)]) == 0
    record = json.loads(out.with_suffix(".json").read_text())
    assert record["epochs"] == 2 and len(record["validation_seeds"]) == 1 and len(record["history"]) == 2
    model = pc.load_run(out)
    assert model(torch.rand(1, 1, 120, 160), torch.rand(1, 1, 60, 80), torch.zeros(1, 3)).shape == (1, 3)
    reserved = write_dataset(tmp_path / "reserved", [5, 20003], 8, rng)
    assert pc.main([*common, "--dataset", str(data), "--dataset", str(reserved)]) == 2


def write_round(directory, seeds, rows, rng):
    directory.mkdir(parents=True, exist_ok=True)
    for seed in seeds:
        np.savez_compressed(
            directory / f"episode_{seed:05}.npz",
            seed=np.int64(seed),
            top=rng.integers(0, 256, (rows, 120, 160), dtype=np.uint8),
            bottom=rng.integers(0, 256, (rows, 60, 80), dtype=np.uint8),
            command=rng.uniform(-1, 1, (rows, 3)).astype(np.float32),
            phase=rng.integers(0, 4, rows, dtype=np.uint8),
            previous=rng.uniform(-1, 1, (rows, 3)).astype(np.float32),
        )
    return directory


def test_a_rounds_rows_keep_their_executed_commands_and_reserved_rounds_are_refused(tmp_path, rng, monkeypatch):
    round_dir = write_round(tmp_path / "round", [4000, 4001], 5, rng)
    pairs = pc.round_episodes(round_dir)
    with np.load(round_dir / "episode_04001.npz") as arrays:
        assert np.array_equal(pairs[1][1], arrays["previous"])
    monkeypatch.setattr(pc, "start_model", lambda path: CNN().eval())
    data = write_dataset(tmp_path / "data", [1, 2, 3], 6, rng)
    out = tmp_path / "run.pt"
    common = ["train", "--start", "models/policy/x", "--out", str(out), "--epochs", "1", "--validation-episodes", "1", "--dataset", str(data)]
    assert pc.main([*common, "--round", str(round_dir)]) == 0
    assert any("round, 2 episodes" in name for name in json.loads(out.with_suffix(".json").read_text())["datasets"])
    assert pc.main([*common, "--round", str(write_round(tmp_path / "selection", [20010], 5, rng))]) == 2
    assert pc.main([*common, "--round", str(tmp_path / "empty")]) == 2


def test_only_the_last_commands_weights_learn_where_asked(tmp_path, rng, monkeypatch):
    start = CNN()
    monkeypatch.setattr(pc, "start_model", lambda path: start.eval())
    data = write_dataset(tmp_path / "data", [1, 2, 3], 8, rng)
    out = tmp_path / "run.pt"
    args = ["train", "--start", "x", "--dataset", str(data), "--out", str(out), "--epochs", "2", "--validation-episodes", "1", "--only-previous"]
    assert pc.main(args) == 0
    model = pc.load_run(out)
    features = start.head[0].in_features
    assert torch.equal(model.hidden.weight[:, :features], start.head[0].weight)
    assert torch.equal(model.hidden.bias, start.head[0].bias) and torch.equal(model.out.weight, start.head[2].weight)
    record = json.loads(out.with_suffix(".json").read_text())
    if record["best_epoch"] > 0:
        assert model.hidden.weight[:, features:].abs().sum() > 0


def test_the_report_tables_each_run_with_its_interval_and_failures(tmp_path, capsys):
    def summary(run, condition, outcomes):
        episodes = [{"seed": 20000 + i, "outcome": o, "failure_class": None if o == "goal" else "walked_off"} for i, o in enumerate(outcomes)]
        return {"engine": "torch (gym, one thread)", "conditions": condition, "run": f"{run}.pt", "episodes": episodes}

    (tmp_path / "treatment-clean.json").write_text(json.dumps(summary("treatment", "clean", ["goal", "goal", "time_limit"])))
    (tmp_path / "control-clean.json").write_text(json.dumps(summary("control", "clean", ["goal", "time_limit", "time_limit"])))
    (tmp_path / "paired.json").write_text(json.dumps({"row": {"goals": [1, 2]}}))  # another tool's file: skipped
    assert pc.main(["report", str(tmp_path)]) == 0
    text = (tmp_path / "README.md").read_text()
    assert "| clean | control | 20000..20002 | 1 / 3 " in text and "| clean | treatment | 20000..20002 | 2 / 3 " in text
    assert text.index("| clean | control") < text.index("| clean | treatment")
    assert pc.main(["report", str(tmp_path / "nothing")]) == 2


def test_a_round_refuses_reserved_seeds_and_a_beta_that_is_no_probability(tmp_path, capsys):
    # Both refusals come before the run is loaded or an environment started.
    common = ["round", str(tmp_path / "absent.pt"), "--out", str(tmp_path / "round")]
    assert pc.main([*common, "--seeds", "20000..20002"]) == 2
    assert "selection seeds [20000, 20001]" in capsys.readouterr().err
    assert pc.main([*common, "--seeds", "5000..5002", "--beta", "1.5"]) == 2
    assert "not a probability" in capsys.readouterr().err
    assert not (tmp_path / "round").exists()
