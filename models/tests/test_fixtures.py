"""The committed fixtures are what their script says: ONNX outputs reproduce the references."""

from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from dribble_models.gating import nearest_cluster
from dribble_models.manifest import load

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


def references(kind: str):
    reference = FIXTURES / kind / "reference"
    meta = load(reference / "reference.toml")
    steps = meta["steps"]
    pixels = np.fromfile(reference / "thumbnails.u8", np.uint8).reshape(steps, -1)
    tops = pixels[:, : 120 * 160].reshape(steps, 1, 1, 120, 160)
    bottoms = pixels[:, 120 * 160 :].reshape(steps, 1, 1, 60, 80)
    commands = np.fromfile(reference / "commands.f32", "<f4").reshape(steps, 3)
    return meta, tops, bottoms, commands


def run(path: Path, **inputs):
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, inputs)


@pytest.mark.parametrize("kind", ["cnn", "hcnn", "rcnn", "cnn-previous"])
def test_fixture_onnx_reproduces_its_reference(kind):
    manifest = load(FIXTURES / kind / "policy.toml")
    meta, tops, bottoms, commands = references(kind)
    scale = np.float32(manifest["normalisation"]["scale"])
    sessions = [ort.InferenceSession(str(FIXTURES / kind / n), providers=["CPUExecutionProvider"]) for n in manifest["networks"]]
    state = {"h_in": np.zeros((1, 1, 64), np.float32), "c_in": np.zeros((1, 1, 64), np.float32)}
    worst = 0.0
    for step in range(meta["steps"]):
        inputs = {"top": tops[step].astype(np.float32) * scale, "bottom": bottoms[step].astype(np.float32) * scale}
        network = 0
        if kind == "hcnn":
            network = nearest_cluster(tops[step], bottoms[step], np.array(manifest["gating"]["centroids"]))
            assert network == meta["clusters"][step]
        if kind == "cnn-previous":
            previous = np.fromfile(FIXTURES / kind / "reference" / "previous.f32", "<f4").reshape(-1, 3)
            (command,) = sessions[0].run(None, {**inputs, "previous": previous[step][None]})
        elif kind == "rcnn":
            command, h, c = sessions[0].run(None, {**inputs, **state})
            state = {"h_in": h, "c_in": c}
        else:
            (command,) = sessions[network].run(None, inputs)
        worst = max(worst, float(np.abs(command[0] - commands[step]).max()))
    print(f"{kind} fixture: max |onnxruntime - PyTorch reference| = {worst:.2e}")
    assert worst <= 1e-5


def test_the_nan_fixture_answers_nan():
    (command,) = run(
        FIXTURES / "nan" / "policy.onnx",
        top=np.full((1, 1, 120, 160), 0.5, np.float32),
        bottom=np.zeros((1, 1, 60, 80), np.float32),
    )
    assert command.shape == (1, 3) and np.isnan(command[0, 0])
