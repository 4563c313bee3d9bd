"""The trainer on a CUDA GPU (`--device cuda`): skipped where PyTorch sees none (CI), run on a
lent GPU machine (the last test runs everywhere). It checks what the module promises of a GPU: the same seed gives the same
model again there, its predictions are the CPU's (full fp32, no TF32), and its checkpoints
load and resume on the CPU."""

import pytest
import torch

from dribble_models import dataset as ds
from dribble_models.networks import CNN, HCNN, RCNN
from dribble_models.prediction import predict
from dribble_models.train import main

from test_train import write_dataset

needs_gpu = pytest.mark.skipif(not torch.cuda.is_available(), reason="PyTorch sees no CUDA GPU")

KINDS = ["cnn", "hcnn", "rcnn", "cnn --modes 2"]


def train(kind, data, out, checkpoints, *extra):
    argv = ["--kind", *kind.split(), "--dataset", str(data), "--out", str(out), "--checkpoint-dir", str(checkpoints)]
    argv += ["--validation-episodes", "1", "--batch-size", "16", "--window", "10", "--lanes", "2", "--threads", "1", *extra]
    assert main(argv) == 0


@needs_gpu
@pytest.mark.parametrize("kind", KINDS)
def test_a_seed_gives_the_same_model_again_on_the_gpu(kind, tmp_path, rng):
    data = write_dataset(tmp_path / "train", [1, 2, 3], 40, rng)
    states = []
    for run in ("a", "b"):
        train(kind, data, tmp_path / f"out-{run}", tmp_path / f"checkpoints-{run}", "--device", "cuda", "--epochs", "2")
        checkpoint = torch.load(tmp_path / f"checkpoints-{run}" / f"{kind.split()[0]}.pt", weights_only=False, map_location="cpu")
        states.append(checkpoint["model"])
    assert states[0].keys() == states[1].keys()
    for name in states[0]:
        assert states[0][name].device.type == "cpu", name  # saved loadable anywhere
        assert torch.equal(states[0][name], states[1][name]), name
    notes = (tmp_path / "out-a" / "policy.toml").read_text()
    assert "trained on cuda (" in notes


@needs_gpu
@pytest.mark.parametrize("kind", ["cnn", "hcnn", "rcnn"])
def test_gpu_predictions_are_the_cpus(kind, rng, tmp_path):
    episodes = ds.load(write_dataset(tmp_path / "data", [1, 2], 30, rng)).episodes
    if kind == "cnn":
        model = CNN()
    elif kind == "rcnn":
        model = RCNN()
    else:
        model = HCNN(rng.uniform(0, 0.5, (4, 10)).astype("float32"))
    on_cpu = predict(model, kind, episodes)
    on_gpu = predict(model.to("cuda"), kind, episodes)
    for cpu, gpu in zip(on_cpu, on_gpu):
        assert abs(cpu - gpu).max() < 1e-4


@needs_gpu
def test_a_gpu_checkpoint_resumes_on_the_cpu(tmp_path, rng, capsys):
    data = write_dataset(tmp_path / "train", [1, 2, 3], 40, rng)
    train("cnn", data, tmp_path / "out", tmp_path / "checkpoints", "--device", "cuda", "--epochs", "1")
    train("cnn", data, tmp_path / "out", tmp_path / "checkpoints", "--device", "cpu", "--epochs", "2")
    assert "1 of 2 epochs done" in capsys.readouterr().err
    assert (tmp_path / "out" / "policy.toml").is_file()


def test_cuda_where_there_is_none_is_a_clear_error(tmp_path, rng, capsys, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    data = write_dataset(tmp_path / "train", [1, 2], 10, rng)
    argv = ["--kind", "cnn", "--dataset", str(data), "--out", str(tmp_path / "out"), "--device", "cuda", "--validation-episodes", "1"]
    assert main(argv) == 2
    assert "PyTorch sees no CUDA GPU" in capsys.readouterr().err
