"""ONNX files agree with PyTorch, carry DESIGN.md's names and shapes, and stand alone."""

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from dribble_models import contract
from dribble_models.export import export_cnn, export_policy, export_rcnn_step
from dribble_models.fixtures import synthetic_pairs
from dribble_models.manifest import TrainingRecord, load
from dribble_models.networks import CNN, FEATURES, HCNN, PAPER_FILTERS, RCNN, Filters, ModalCNN, PreviousCommandCNN, to_network_input

TOLERANCE = 1e-5
RECORD = TrainingRecord(dataset="test", epochs=0)


def session(path: Path) -> ort.InferenceSession:
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def test_flattened_features_are_2560():
    top, bottom = to_network_input(np.zeros((1, 120, 160), np.uint8), np.zeros((1, 60, 80), np.uint8))
    assert CNN().features(top, bottom).shape == (1, 2560) == (1, FEATURES)


def test_a_narrow_cnn_has_the_paper_layers_with_fewer_filters():
    narrow = Filters.parse("8,16,4,8")
    assert PAPER_FILTERS.features == FEATURES and narrow.features == 16 * 7 * 10 + 8 * 4 * 5 == 1280
    top, bottom = to_network_input(np.zeros((2, 120, 160), np.uint8), np.zeros((2, 60, 80), np.uint8))
    for model in (CNN(narrow), ModalCNN(2, narrow)):
        assert model.features(top, bottom).shape == (2, 1280)
        convolutions = [m for m in model.modules() if isinstance(m, torch.nn.Conv2d)]
        assert [c.out_channels for c in convolutions] == [8, 16, 4, 8]
        assert [c.kernel_size for c in convolutions] == [(5, 5)] * 4 and [c.stride for c in convolutions] == [(2, 2)] * 4
    for text in ("8,16,4", "8,16,4,x", "8,16,0,8", "8,16,4,8,1"):
        with pytest.raises(ValueError, match="four counts|positive"):
            Filters.parse(text)


@pytest.mark.parametrize("filters", [PAPER_FILTERS, Filters(8, 16, 4, 8)], ids=["paper", "narrow"])
def test_cnn_onnx_matches_pytorch(tmp_path, rng, filters):
    model = CNN(filters).eval()
    path = export_cnn(model, tmp_path / "cnn.onnx")
    tops, bottoms = synthetic_pairs(rng, 8)
    runtime = session(path)
    worst = 0.0
    for top_u8, bottom_u8 in zip(tops, bottoms):
        top, bottom = to_network_input(top_u8, bottom_u8)
        with torch.no_grad():
            expected = model(top, bottom).numpy()
        (got,) = runtime.run(None, {"top": top.numpy(), "bottom": bottom.numpy()})
        worst = max(worst, float(np.abs(got - expected).max()))
    print(f"CNN: max |ONNX - PyTorch| = {worst:.2e}")
    assert worst <= TOLERANCE


def test_hcnn_onnx_matches_pytorch_for_every_network_and_gate(tmp_path, rng):
    tops, bottoms = synthetic_pairs(rng, 16)
    from dribble_models.gating import fit_centroids, gating_feature

    centroids = fit_centroids(np.stack([gating_feature(t, b) for t, b in zip(tops, bottoms)]), 4, seed=1)
    model = HCNN(centroids).eval()
    manifest = load(export_policy(model, tmp_path, RECORD))
    assert manifest["kind"] == "hcnn" and manifest["gating"]["clusters"] == 4
    runtimes = [session(tmp_path / name) for name in manifest["networks"]]
    worst = 0.0
    for top_u8, bottom_u8 in zip(tops, bottoms):
        with torch.no_grad():
            expected, k = model.forward_u8(top_u8, bottom_u8)
        top, bottom = to_network_input(top_u8, bottom_u8)
        (got,) = runtimes[k].run(None, {"top": top.numpy(), "bottom": bottom.numpy()})
        worst = max(worst, float(np.abs(got - expected.numpy()).max()))
    print(f"H-CNN: max |ONNX - PyTorch| = {worst:.2e}")
    assert worst <= TOLERANCE


def test_rcnn_stepped_from_distinct_nonzero_state_equals_the_whole_sequence(tmp_path, rng):
    """The exported step, fed its own state back, must equal PyTorch's LSTM over the whole
    sequence; h and c start distinct and non-zero so a swap of the two cannot hide."""
    model = RCNN().eval()
    runtime = session(export_rcnn_step(model, tmp_path / "rcnn.onnx"))
    steps = 20
    tops, bottoms = synthetic_pairs(rng, steps)
    top, bottom = to_network_input(tops, bottoms)
    h0 = torch.linspace(-0.8, 0.8, 64).reshape(1, 1, 64)
    c0 = torch.linspace(1.5, -0.3, 64).reshape(1, 1, 64)
    with torch.no_grad():
        expected, (h_end, c_end) = model(top.unsqueeze(0), bottom.unsqueeze(0), (h0, c0))
    h, c = h0.numpy(), c0.numpy()
    worst = 0.0
    for t in range(steps):
        command, h, c = runtime.run(
            ["command", "h_out", "c_out"],
            {"top": top[t : t + 1].numpy(), "bottom": bottom[t : t + 1].numpy(), "h_in": h, "c_in": c},
        )
        worst = max(worst, float(np.abs(command - expected[0, t].numpy()).max()))
    worst_state = max(float(np.abs(h - h_end.numpy()).max()), float(np.abs(c - c_end.numpy()).max()))
    print(f"R-CNN: max |ONNX step - PyTorch sequence| = {worst:.2e}, final state {worst_state:.2e}")
    assert worst <= TOLERANCE
    assert worst_state <= TOLERANCE


def test_rcnn_state_inputs_are_not_interchangeable(tmp_path, rng):
    """Guards the test above: swapping h and c must change the answer."""
    model = RCNN().eval()
    runtime = session(export_rcnn_step(model, tmp_path / "rcnn.onnx"))
    top, bottom = to_network_input(*synthetic_pairs(rng, 1))
    h = np.full((1, 1, 64), 0.7, np.float32)
    c = np.full((1, 1, 64), -0.4, np.float32)
    inputs = {"top": top.numpy(), "bottom": bottom.numpy()}
    straight = runtime.run(["command"], {**inputs, "h_in": h, "c_in": c})[0]
    swapped = runtime.run(["command"], {**inputs, "h_in": c, "c_in": h})[0]
    assert np.abs(straight - swapped).max() > 1e-3


@pytest.mark.parametrize("kind", ["cnn", "rcnn"])
def test_onnx_has_the_contract_names_shapes_and_opset_in_one_file(tmp_path, kind):
    model = CNN() if kind == "cnn" else RCNN()
    manifest_path = export_policy(model, tmp_path, RECORD)
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == ["policy.onnx", "policy.toml"], "weights must live inside the ONNX file"
    graph = onnx.load(str(tmp_path / "policy.onnx"))
    assert [o.version for o in graph.opset_import if o.domain in ("", "ai.onnx")] == [contract.OPSET]

    def shapes(values):
        return {v.name: [d.dim_value for d in v.type.tensor_type.shape.dim] for v in values}

    inputs, outputs = shapes(graph.graph.input), shapes(graph.graph.output)
    assert inputs["top"] == [1, 1, 120, 160] and inputs["bottom"] == [1, 1, 60, 80]
    assert outputs["command"] == [1, 3]
    if kind == "rcnn":
        assert inputs["h_in"] == inputs["c_in"] == outputs["h_out"] == outputs["c_out"] == [1, 1, 64]
    manifest = load(manifest_path)
    assert manifest["inputs"]["top"] == {"name": "top", "shape": [1, 1, 120, 160]}
    assert manifest["command_scale"] == contract.COMMAND_SCALE
    assert ("recurrent" in manifest) == (kind == "rcnn")


def test_the_controllers_standardisation_is_the_trainers(rng):
    """`contract.network_input` (the controller's arithmetic) and the trainer's
    `networks.standardised` on scaled thumbnails give the same values, a flat thumbnail
    divided by the floor; a gain and offset of the pixels changes nothing."""
    from dribble_models.networks import standardised

    pixels = rng.integers(0, 256, (3, 120, 160), dtype=np.uint8)
    pixels[2] = 100
    pixels[2, 0, :4] = 104
    controller = contract.network_input(pixels, standardise=True)
    trainer = standardised(torch.from_numpy(contract.network_input(pixels)[:, None]))[:, 0].numpy()
    assert np.abs(controller - trainer).max() < 1e-4
    assert np.allclose(controller[:2].mean(axis=(1, 2)), 0, atol=1e-5) and np.allclose(controller[:2].std(axis=(1, 2)), 1, atol=1e-5)
    # Four pixels of 104 among 100s: a spread of about 0.03 levels, so the floor of 4 divides.
    assert controller[2, 0, 0] == pytest.approx((104 - (100 + 16 / (120 * 160))) / 4, abs=1e-6)
    dim = (pixels[:2] // 3 + 20).astype(np.uint8)
    bright = (dim * 2 + 15).astype(np.uint8)
    assert np.abs(contract.network_input(dim, True) - contract.network_input(bright, True)).max() < 1e-5


def test_a_standardised_policy_exports_the_network_alone(tmp_path, rng):
    """The manifest says `standardise = true`; the ONNX file holds no standardisation: fed
    what the controller computes, it answers as the PyTorch model fed scaled pixels; loaded
    back as a start, the model standardises again."""
    import tomllib

    from dribble_models.networks import set_standardise, standardises
    from dribble_models.shipped_weights import load_shipped_weights

    model = CNN(Filters(4, 8, 4, 8)).eval()
    set_standardise(model, True)
    manifest = export_policy(model, tmp_path, RECORD)
    assert standardises(model), "export leaves the model as it found it"
    assert tomllib.loads(Path(manifest).read_text())["normalisation"]["standardise"] is True
    runtime = session(tmp_path / "policy.onnx")
    tops, bottoms = synthetic_pairs(rng, 4)
    for top_u8, bottom_u8 in zip(tops, bottoms):
        top, bottom = to_network_input(top_u8, bottom_u8)
        with torch.no_grad():
            expected = model(top, bottom).numpy()
        feed = {"top": contract.network_input(top_u8[None, None], True), "bottom": contract.network_input(bottom_u8[None, None], True)}
        (got,) = runtime.run(None, feed)
        assert np.abs(got - expected).max() < 1e-4
    restarted = CNN(Filters(4, 8, 4, 8))
    load_shipped_weights(restarted, tmp_path, "cnn")
    assert standardises(restarted)
    plain = CNN(Filters(4, 8, 4, 8)).eval()
    assert "standardise" not in tomllib.loads(Path(export_policy(plain, tmp_path / "plain", RECORD)).read_text())["normalisation"]


def test_a_cnn_reading_its_last_command_exports_three_inputs_and_starts_as_its_cnn(tmp_path, rng):
    cnn = CNN().eval()
    model = PreviousCommandCNN.from_cnn(cnn).eval()
    tops, bottoms = synthetic_pairs(rng, 4)
    top, bottom = to_network_input(tops, bottoms)
    previous = torch.from_numpy(rng.uniform(-1, 1, (4, 3)).astype(np.float32))
    with torch.no_grad():
        # The last command's weights start at zero: the start's function, whatever it is.
        assert torch.allclose(model(top, bottom, previous), cnn(top, bottom), atol=1e-6)
        model.hidden.weight[:, -3:] = torch.from_numpy(rng.normal(0, 0.5, (128, 3)).astype(np.float32))
        expected = model(top, bottom, previous).numpy()
    manifest_path = export_policy(model, tmp_path, RECORD)
    manifest = load(manifest_path)
    assert manifest["inputs"]["previous"] == {"name": contract.PREVIOUS_INPUT, "shape": [1, 3]}
    graph = onnx.load(str(tmp_path / "policy.onnx"))
    assert [v.name for v in graph.graph.input] == ["top", "bottom", "previous"]
    runtime = session(tmp_path / "policy.onnx")
    got = np.concatenate(
        [
            runtime.run(None, {"top": top[i : i + 1].numpy(), "bottom": bottom[i : i + 1].numpy(), "previous": previous[i : i + 1].numpy()})[0]
            for i in range(4)
        ]
    )
    assert np.abs(got - expected).max() <= TOLERANCE
    # The plain CNN's manifest names no last command.
    assert "previous" not in load(export_policy(cnn, tmp_path / "plain", RECORD))["inputs"]
