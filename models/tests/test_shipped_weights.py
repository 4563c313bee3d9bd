"""A shipped model's weights come back into PyTorch exactly, or the start is refused."""

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from dribble_models.export import export_policy
from dribble_models.fixtures import synthetic_pairs
from dribble_models.manifest import TrainingRecord
from dribble_models.networks import CNN, HCNN, RCNN, ModalCNN, to_network_input
from dribble_models.shipped_weights import ShippedWeightsError, is_shipped_model, load_shipped_weights
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
