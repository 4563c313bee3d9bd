"""Post-training int8 quantization: calibrated on training rows only, 7-bit weights, hidden
layers only, a manifest the controller reads, and an int8 network that answers close to the
float one (onnxruntime runs both)."""

import hashlib
import os
import subprocess
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import tomllib
import torch

from dribble_models import contract
from dribble_models.export import export_policy
from dribble_models.manifest import TrainingRecord
from dribble_models.networks import CNN, RCNN
from dribble_models.quantize import QuantizeError, calibration_rows, hidden_layers, main, quantize_policy
from dribble_models import dataset as ds

from test_dataset import dribble_binary
from test_train import write_dataset


def float_policy(tmp_path: Path, model, train: Path) -> Path:
    record = TrainingRecord(dataset="train", epochs=0, dataset_hash=ds.load(train).content_hash, validation_seeds=[3])
    directory = tmp_path / "float"
    export_policy(model.eval(), directory, record)
    return directory


def feeds(rng, count):
    scale = np.float32(contract.INPUT_SCALE)
    for _ in range(count):
        yield {
            "top": rng.integers(0, 256, (1, 1, 120, 160)).astype(np.float32) * scale,
            "bottom": rng.integers(0, 256, (1, 1, 60, 80)).astype(np.float32) * scale,
        }


def test_calibration_rows_leave_out_validation_seeds_and_follow_the_seed(tmp_path, rng):
    train = ds.load(write_dataset(tmp_path / "train", [1, 2, 3], 10, rng))
    rows = calibration_rows(train, 12, seed=5, exclude_seeds={3})
    assert len(rows) == 12 and {s for s, _ in rows} <= {1, 2}
    assert rows == calibration_rows(train, 12, seed=5, exclude_seeds={3})
    assert rows != calibration_rows(train, 12, seed=6, exclude_seeds={3})


def test_a_cnn_quantizes_its_hidden_layers_in_7_bits_and_answers_near_the_float(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2, 3], 20, rng)
    policy = float_policy(tmp_path, CNN(), train)
    out = tmp_path / "int8"
    record = quantize_policy(policy, train, out, frames=32, seed=0)

    model = onnx.load(str(out / "policy.onnx"))
    assert len(hidden_layers(onnx.load(str(policy / "policy.onnx")))) == 5  # 4 convolutions, 1 hidden dense
    weights = [i for i in model.graph.initializer if i.data_type == onnx.TensorProto.INT8 and i.dims and len(i.dims) > 1]
    assert len(weights) == 5
    assert all(np.abs(onnx.numpy_helper.to_array(w)).max() <= 64 for w in weights)
    # The command's own layer stays float: its weights are not an int8 initialiser.
    assert not any(i.name.startswith("head.2.weight") and i.data_type == onnx.TensorProto.INT8 for i in model.graph.initializer)

    manifest = tomllib.loads((out / "policy.toml").read_text())
    assert manifest["precision"] == "int8"
    assert manifest["quantization"]["calibration_frames"] == 32
    assert manifest["quantization"]["networks"][0]["activation_scales"] == pytest.approx(record["activation_scales"][0])

    float_run = ort.InferenceSession(str(policy / "policy.onnx"), providers=["CPUExecutionProvider"])
    int8_run = ort.InferenceSession(str(out / "policy.onnx"), providers=["CPUExecutionProvider"])
    worst = 0.0
    for feed in feeds(rng, 8):
        (a,) = float_run.run(None, feed)
        (b,) = int8_run.run(None, feed)
        worst = max(worst, float(np.abs(a - b).max()))
    print(f"int8 vs float: max |difference| {worst:.4f}")
    # An untrained network's outputs are about 0.1; int8 keeps them within a few percent.
    assert 0 < worst < 0.02


def test_the_rcnn_keeps_its_lstm_in_floats(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2], 12, rng)
    policy = float_policy(tmp_path, RCNN(), train)
    quantize_policy(policy, train, tmp_path / "int8", frames=8, seed=0)
    model = onnx.load(str(tmp_path / "int8" / "policy.onnx"))
    lstm = [n for n in model.graph.node if n.op_type == "LSTM"]
    assert lstm and all(not name.endswith("DequantizeLinear_Output") for name in lstm[0].input[1:3])


def test_calibrating_on_another_dataset_is_refused(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2], 5, rng)
    other = write_dataset(tmp_path / "other", [500], 5, rng)
    policy = float_policy(tmp_path, CNN(), train)
    with pytest.raises(QuantizeError, match="is neither the dataset.*not training seeds"):
        quantize_policy(policy, other, tmp_path / "int8")
    assert main(["--policy", str(policy), "--dataset", str(other), "--out", str(tmp_path / "x")]) == 2
    # A validation seed of the policy (3), re-recorded, is not a training episode either.
    validation = write_dataset(tmp_path / "validation", [3], 5, rng)
    with pytest.raises(QuantizeError, match="not training seeds"):
        quantize_policy(policy, validation, tmp_path / "int8")


@pytest.mark.parametrize("seed", [10_000, 20_049, 30_000])
def test_calibration_refuses_the_seeds_kept_for_choosing_and_reporting(tmp_path, rng, seed):
    train = write_dataset(tmp_path / "train", [1, 2], 5, rng)
    policy = float_policy(tmp_path, CNN(), train)
    reserved = write_dataset(tmp_path / "reserved", [2, seed], 5, rng)
    with pytest.raises(QuantizeError, match="kept for choosing and reporting.*never calibration data"):
        quantize_policy(policy, reserved, tmp_path / "int8")


def test_episodes_re_recorded_from_training_seeds_by_the_same_teacher_may_calibrate(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2], 5, rng)
    part = write_dataset(tmp_path / "part", [2], 5, rng)
    policy = float_policy(tmp_path, CNN(), train)
    record = quantize_policy(policy, part, tmp_path / "int8", frames=4)
    assert record["calibration_dataset_hash"] == ds.load(part).content_hash
    assert record["calibration_frames"] == 4


def test_the_committed_int8_fixture_is_the_cnn_fixture_quantized_and_answers_near_it():
    fixtures = Path(__file__).resolve().parents[1] / "fixtures"
    manifest = tomllib.loads((fixtures / "cnn-int8" / "policy.toml").read_text())
    float_hash = hashlib.sha256((fixtures / "cnn" / "policy.onnx").read_bytes()).hexdigest()
    assert manifest["precision"] == "int8"
    assert manifest["quantization"]["float_networks_sha256"] == [float_hash]
    reference = fixtures / "cnn-int8" / "reference"
    pixels = np.fromfile(reference / "thumbnails.u8", np.uint8).reshape(-1, 120 * 160 + 60 * 80)
    expected = np.fromfile(reference / "commands.f32", "<f4").reshape(-1, 3)
    scale = np.float32(contract.INPUT_SCALE)
    int8 = ort.InferenceSession(str(fixtures / "cnn-int8" / "policy.onnx"), providers=["CPUExecutionProvider"])
    fp32 = ort.InferenceSession(str(fixtures / "cnn" / "policy.onnx"), providers=["CPUExecutionProvider"])
    for step, row in enumerate(pixels):
        feed = {
            "top": row[: 120 * 160].reshape(1, 1, 120, 160).astype(np.float32) * scale,
            "bottom": row[120 * 160 :].reshape(1, 1, 60, 80).astype(np.float32) * scale,
        }
        (command,) = int8.run(["command"], feed)
        np.testing.assert_allclose(command[0], expected[step], atol=1e-6)
        (reference_command,) = fp32.run(["command"], feed)
        assert np.abs(command - reference_command).max() < 0.02
    model = onnx.load(str(fixtures / "cnn-int8" / "policy.onnx"))
    quantized = [n for n in model.graph.node if n.op_type == "DequantizeLinear" and n.input[0].endswith("weight_quantized")]
    assert len(quantized) == 5  # four convolutions and the hidden dense layer


def two_forward_passes(manifest: Path) -> subprocess.CompletedProcess:
    """`dribble-controller forward` of the policy at `manifest`, two passes, warnings only."""
    controller = Path(dribble_binary()).with_name("dribble-controller")
    return subprocess.run(
        [str(controller), "forward", "--no-peak", "--steps", "2", "--policy", str(manifest)],
        capture_output=True,
        text=True,
        env=os.environ | {"RUST_LOG": "warn"},
    )


def test_the_controller_reads_the_int8_manifest(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2], 8, rng)
    out = tmp_path / "int8"
    quantize_policy(float_policy(tmp_path, CNN(), train), train, out, frames=8)
    said = two_forward_passes(out / "policy.toml")
    assert said.returncode == 0, said.stderr
    assert "int8" in said.stdout and "2 forward pass(es)" in said.stdout
    # The compiled engine runs it in integers (not tract).
    assert "int8)" in said.stdout, said.stdout


def test_a_cnn_reading_its_last_command_is_calibrated_on_it_and_runs_in_integers(tmp_path, rng):
    """The calibration feeds give the network the command executed before each row; the
    controller's compiled engine runs the int8 file in integers, its check against tract
    made on random last commands."""
    from dribble_models.networks import PreviousCommandCNN

    train = write_dataset(tmp_path / "train", [1, 2], 8, rng)
    model = PreviousCommandCNN.from_cnn(CNN())
    with torch.no_grad():
        model.hidden.weight[:, -3:] = torch.from_numpy(rng.normal(0, 0.5, (128, 3)).astype(np.float32))
    out = tmp_path / "int8"
    quantize_policy(float_policy(tmp_path, model, train), train, out, frames=8)
    manifest = tomllib.loads((out / "policy.toml").read_text())
    assert manifest["inputs"]["previous"] == {"name": "previous", "shape": [1, 3]}
    assert [i.name for i in onnx.load(str(out / "policy.onnx")).graph.input] == ["top", "bottom", "previous"]
    said = two_forward_passes(out / "policy.toml")
    assert said.returncode == 0, said.stderr
    assert "int8)" in said.stdout, said.stdout
