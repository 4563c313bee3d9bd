"""The committed copy of a modal CNN: its hypotheses and logits as outputs, the same command."""

import json
import tomllib

import numpy as np
import onnxruntime as ort
import pytest
import torch

from dribble_models import contract
from dribble_models.commitment import write_committed
from dribble_models.export import export_policy
from dribble_models.fixtures import synthetic_pairs
from dribble_models.manifest import TrainingRecord
from dribble_models.networks import CNN, ModalCNN, to_network_input


def test_the_committed_copy_outputs_every_hypothesis_and_keeps_the_command(tmp_path):
    torch.manual_seed(3)
    model = ModalCNN(2).eval()
    export_policy(model, tmp_path / "modal", TrainingRecord(dataset="test", epochs=0, teacher="observable"))
    manifest = write_committed(tmp_path / "modal", 0.75, tmp_path / "committed")

    table = tomllib.loads(manifest.read_text())
    assert table["hypotheses"] == {"count": 2, "commands": "hypotheses", "logits": "logits", "switch_margin": 0.75}
    assert table["training"]["teacher"] == "observable", "the training record is kept"

    tops, bottoms = synthetic_pairs(np.random.default_rng(5), 6)
    top, bottom = to_network_input(tops, bottoms)
    session = ort.InferenceSession(str(manifest.parent / "policy.onnx"), providers=["CPUExecutionProvider"])
    for i in range(len(tops)):
        feed = {contract.TOP_INPUT: top[i : i + 1].numpy(), contract.BOTTOM_INPUT: bottom[i : i + 1].numpy()}
        command, hypotheses, logits = session.run(["command", "hypotheses", "logits"], feed)
        with torch.no_grad():
            expected_hypotheses, expected_logits = model.forward_all(top[i : i + 1], bottom[i : i + 1])
        np.testing.assert_allclose(hypotheses, expected_hypotheses.numpy(), atol=1e-5)
        np.testing.assert_allclose(logits, expected_logits.numpy(), atol=1e-5)
        # The graph's own choice is the hypothesis of the largest logit, exactly.
        np.testing.assert_array_equal(command[0], hypotheses[0, int(np.argmax(logits[0]))])


def test_only_a_modal_cnn_can_be_committed(tmp_path):
    export_policy(CNN().eval(), tmp_path / "cnn", TrainingRecord(dataset="test", epochs=0))
    with pytest.raises(SystemExit, match="modal CNN"):
        write_committed(tmp_path / "cnn", 1.0, tmp_path / "out")
    torch.manual_seed(3)
    export_policy(ModalCNN(2).eval(), tmp_path / "modal", TrainingRecord(dataset="test", epochs=0))
    with pytest.raises(SystemExit, match="not be negative"):
        write_committed(tmp_path / "modal", -1.0, tmp_path / "out")
    committed = write_committed(tmp_path / "modal", 1.0, tmp_path / "out")
    with pytest.raises(SystemExit, match="without a \\[hypotheses\\] table"):
        write_committed(committed.parent, 1.0, tmp_path / "again")


def test_the_robot_scores_a_committed_copy_and_counts_its_switches(tmp_path, rng):
    """`dribble score` runs the committed copy through the controller's commitment: at margin
    0 it scores exactly what the modal CNN does, and it reports the switches it made."""
    from test_train import main as train_main
    from test_train import run_score, write_dataset

    train = write_dataset(tmp_path / "train", [1, 2], 24, rng)
    test = write_dataset(tmp_path / "test", [10000], 40, rng)
    out = tmp_path / "modal"
    argv = ["--kind", "cnn", "--modes", "2", "--dataset", str(train), "--test-dataset", str(test), "--out", str(out)]
    argv += ["--epochs", "1", "--validation-episodes", "1", "--batch-size", "16"]
    argv += ["--checkpoint-dir", str(tmp_path / "checkpoints"), "--threads", "1"]
    assert train_main(argv) == 0

    def score(policy, name):
        result = run_score(policy / "policy.toml", test, tmp_path, "--json", str(tmp_path / f"{name}.json"))
        assert result.returncode == 0, result.stdout + result.stderr
        return result.stdout, json.loads((tmp_path / f"{name}.json").read_text())

    _, plain = score(out, "plain")
    assert plain["hypothesis_switches"] is None
    stdout, zero = score(write_committed(out, 0.0, tmp_path / "zero").parent, "zero")
    assert zero["error"] == plain["error"] and zero["rows"] == 40
    assert f"hypothesis switches: {zero['hypothesis_switches']} in 40 rows" in stdout
    _, held = score(write_committed(out, 1.0e6, tmp_path / "held").parent, "held")
    assert held["hypothesis_switches"] == 0 <= zero["hypothesis_switches"]
