"""A shipped model's weights come back into PyTorch exactly, or the start is refused."""

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from dribble_models.export import export_policy
from dribble_models.fixtures import synthetic_pairs
from dribble_models.manifest import TrainingRecord
from dribble_models.networks import CNN, HCNN, RCNN, Filters, ModalCNN, to_network_input
from dribble_models.shipped_weights import (
    ShippedWeightsError,
    is_shipped_model,
    load_pruned_weights,
    load_shipped_weights,
)
from dribble_models.train import main as train_main

RECORD = TrainingRecord(dataset="test", epochs=0)
COMMITTED = Path(__file__).resolve().parents[1] / "policy" / "cnn-observable"


def test_every_parameter_comes_back_bit_for_bit(tmp_path):
    torch.manual_seed(3)
    shipped = CNN().eval()
    export_policy(shipped, tmp_path, RECORD)
    torch.manual_seed(4)
    started = CNN()
    load_shipped_weights(started, tmp_path, "cnn")
    for name, value in shipped.state_dict().items():
        assert torch.equal(started.state_dict()[name], value), name
    # The manifest file names the same model as its directory.
    again = CNN()
    load_shipped_weights(again, tmp_path / "policy.toml", "cnn")
    assert all(torch.equal(again.state_dict()[k], v) for k, v in shipped.state_dict().items())


def test_the_committed_observable_cnn_answers_as_its_onnx_file(rng):
    import onnxruntime as ort

    model = CNN().eval()
    load_shipped_weights(model, COMMITTED, "cnn")
    runtime = ort.InferenceSession(str(COMMITTED / "policy.onnx"), providers=["CPUExecutionProvider"])
    tops, bottoms = synthetic_pairs(rng, 4)
    for top_u8, bottom_u8 in zip(tops, bottoms):
        top, bottom = to_network_input(top_u8, bottom_u8)
        with torch.no_grad():
            expected = model(top, bottom).numpy()
        (got,) = runtime.run(None, {"top": top.numpy(), "bottom": bottom.numpy()})
        assert np.abs(got - expected).max() <= 1e-5


def test_other_networks_and_precisions_are_refused_with_the_reason(tmp_path):
    export_policy(ModalCNN(2).eval(), tmp_path / "modal", RECORD)
    with pytest.raises(ShippedWeightsError, match="initializer"):
        load_shipped_weights(CNN(), tmp_path / "modal", "cnn")
    export_policy(RCNN().eval(), tmp_path / "rcnn", RECORD)
    with pytest.raises(ShippedWeightsError, match="a rcnn model, this run trains a cnn"):
        load_shipped_weights(CNN(), tmp_path / "rcnn", "cnn")
    with pytest.raises(ShippedWeightsError, match="no initializer|no parameter"):
        load_shipped_weights(RCNN(), tmp_path / "rcnn", "rcnn")
    centroids = np.random.default_rng(0).random((4, 10)).astype(np.float32)
    export_policy(HCNN(centroids).eval(), tmp_path / "hcnn", RECORD)
    with pytest.raises(ShippedWeightsError, match="4 networks"):
        load_shipped_weights(HCNN(centroids), tmp_path / "hcnn", "hcnn")
    int8 = COMMITTED.parent / "cnn-observable-int8"
    with pytest.raises(ShippedWeightsError, match="precision int8"):
        load_shipped_weights(CNN(), int8, "cnn")
    with pytest.raises(ShippedWeightsError, match="not a model directory"):
        load_shipped_weights(CNN(), tmp_path / "nothing", "cnn")
    assert not is_shipped_model(tmp_path / "nothing.pt")


def test_training_starts_from_a_shipped_model_and_refuses_one_it_cannot_take(tmp_path, rng, capsys):
    from test_train import write_dataset

    train = write_dataset(tmp_path / "train", [1, 2], 12, rng)
    torch.manual_seed(5)
    shipped = CNN().eval()
    export_policy(shipped, tmp_path / "shipped", RECORD)
    common = ["--kind", "cnn", "--dataset", str(train), "--epochs", "1", "--threads", "1",
              "--validation-episodes", "1", "--batch-size", "4"]
    # With a learning rate of 0 the run keeps the weights it started from.
    train_main(common + ["--out", str(tmp_path / "out"), "--init-from", str(tmp_path / "shipped"), "--lr", "0",
                         "--checkpoint-dir", str(tmp_path / "ck")])
    kept = CNN()
    load_shipped_weights(kept, tmp_path / "out", "cnn")
    assert all(torch.equal(kept.state_dict()[k], v) for k, v in shipped.state_dict().items())
    assert "started from the kept weights of" in (tmp_path / "out" / "policy.toml").read_text()
    export_policy(RCNN().eval(), tmp_path / "rcnn", RECORD)
    refused = train_main(common + ["--out", str(tmp_path / "out2"), "--init-from", str(tmp_path / "rcnn"),
                                   "--checkpoint-dir", str(tmp_path / "ck2")])
    assert refused != 0
    assert re.search(r"--init-from: .*a rcnn model, this run trains a cnn", capsys.readouterr().err)
    assert not (tmp_path / "out2" / "policy.toml").exists()


def test_a_modal_run_starts_from_a_one_output_cnn_with_its_commands(tmp_path, rng):
    from test_train import write_dataset

    train = write_dataset(tmp_path / "train", [1, 2], 12, rng)
    torch.manual_seed(6)
    shipped = CNN().eval()
    export_policy(shipped, tmp_path / "shipped", RECORD)
    top, bottom = to_network_input(rng.integers(0, 256, (4, 120, 160), dtype=np.uint8), rng.integers(0, 256, (4, 60, 80), dtype=np.uint8))
    widened = ModalCNN.widened(shipped, 2).eval()
    with torch.no_grad():
        hypotheses, logits = widened.forward_all(top, bottom)
        expected = shipped(top, bottom)
        # Each hypothesis is the start's command moved sideways (+0.5, -0.5), the choice tied,
        # so the network sends the start's command.
        assert torch.allclose(hypotheses[:, 0] - expected, torch.tensor([0.0, 0.5, 0.0]), atol=1e-5)
        assert torch.allclose(hypotheses[:, 1] - expected, torch.tensor([0.0, -0.5, 0.0]), atol=1e-5)
        assert torch.equal(logits, torch.zeros_like(logits))
        assert torch.allclose(widened(top, bottom), expected, atol=1e-5)
    # The trainer takes the same start: with a learning rate of 0 the exported two-hypothesis
    # network still answers as the one-output start.
    common = ["--kind", "cnn", "--modes", "2", "--dataset", str(train), "--epochs", "1", "--threads", "1",
              "--validation-episodes", "1", "--batch-size", "4", "--lr", "0"]
    assert train_main(common + ["--out", str(tmp_path / "out"), "--init-from", str(tmp_path / "shipped"),
                                "--checkpoint-dir", str(tmp_path / "ck")]) == 0
    kept = ModalCNN(2)
    load_shipped_weights(kept, tmp_path / "out", "cnn")
    with torch.no_grad():
        assert torch.allclose(kept.eval()(top, bottom), expected, atol=1e-5)
    assert "head widened to the hypotheses" in (tmp_path / "out" / "policy.toml").read_text()
    # The notes say what the start went through: a `pixel / 255` start re-expressed for
    # standardised input, a standardised two-hypothesis start neither re-expressed nor widened.
    assert train_main(common + ["--out", str(tmp_path / "std"), "--init-from", str(tmp_path / "out"),
                                "--standardise-input", "--checkpoint-dir", str(tmp_path / "ck2")]) == 0
    notes = (tmp_path / "std" / "policy.toml").read_text()
    assert "re-expressed" in notes and "widened" not in notes
    assert train_main(common + ["--out", str(tmp_path / "again"), "--init-from", str(tmp_path / "std"),
                                "--standardise-input", "--checkpoint-dir", str(tmp_path / "ck3")]) == 0
    notes = (tmp_path / "again" / "policy.toml").read_text()
    assert "re-expressed" not in notes and "widened" not in notes


def silenced(model: CNN, branch: str, layer: int, filters: list[int]) -> None:
    """Zeroes the given filters of one convolution and their bias: their outputs are 0 after ReLU."""
    with torch.no_grad():
        conv = getattr(model.features, branch)[layer]
        conv.weight[filters] = 0.0
        conv.bias[filters] = -1.0


def test_pruning_away_silent_filters_keeps_the_function(tmp_path, rng):
    # Filters whose ReLU output is always 0 carry nothing: a network pruned to the others
    # (the largest L1 norms) must answer exactly as the wide one, which checks the kept
    # input channels of the next convolution and the dense columns of the flattening.
    torch.manual_seed(5)
    wide = CNN(Filters(8, 16, 4, 8)).eval()
    silenced(wide, "top", 0, [1, 4, 6, 7])
    silenced(wide, "top", 3, [0, 5, 9, 10, 11, 15])
    silenced(wide, "bottom", 0, [2])
    silenced(wide, "bottom", 3, [3, 4])
    export_policy(wide, tmp_path, RECORD)
    narrow = CNN(Filters(4, 10, 3, 6)).eval()
    kept = load_pruned_weights(narrow, tmp_path)
    assert kept == {
        "top first": [0, 2, 3, 5],
        "top second": [1, 2, 3, 4, 6, 7, 8, 12, 13, 14],
        "bottom first": [0, 1, 3],
        "bottom second": [0, 1, 2, 5, 6, 7],
    }
    top, bottom = to_network_input(*synthetic_pairs(rng, 6))
    with torch.no_grad():
        assert torch.allclose(narrow(top, bottom), wide(top, bottom), atol=1e-6)


def test_pruning_to_the_same_widths_copies_every_weight(tmp_path):
    torch.manual_seed(6)
    wide = CNN(Filters(4, 8, 2, 4)).eval()
    export_policy(wide, tmp_path, RECORD)
    same = CNN(Filters(4, 8, 2, 4))
    load_pruned_weights(same, tmp_path)
    for name, value in wide.state_dict().items():
        assert torch.equal(same.state_dict()[name], value), name


def test_pruning_cannot_add_filters(tmp_path):
    export_policy(CNN(Filters(4, 8, 2, 4)).eval(), tmp_path, RECORD)
    with pytest.raises(ShippedWeightsError, match="fewer than"):
        load_pruned_weights(CNN(Filters(8, 8, 2, 4)), tmp_path)
