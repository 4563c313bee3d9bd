"""The Keras file written for B-Human's CompiledNN is the same network as the ONNX one, and
the comparison's page reads its result file. CompiledNN itself is not built for the suite
(`scripts/setup --compiled-nn`): the Keras model is evaluated here layer by layer, as Keras
defines each layer, channels last."""

import json
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from dribble_models import compiled_nn, compiled_nn_report

REPOSITORY = Path(__file__).resolve().parents[2]
FIXTURE = REPOSITORY / "models" / "fixtures" / "cnn" / "policy.onnx"


def keras_forward(model: compiled_nn.KerasModel, outputs: list[str], feeds: dict[str, np.ndarray]) -> np.ndarray:
    """Keras' functional model on one sample, every layer from its own definition."""
    values: dict[str, np.ndarray] = {}
    for layer in model.layers:
        name, config, kind = layer["name"], layer["config"], layer["class_name"]
        inbound = [values[source] for source, *_ in layer["inbound_nodes"][0]] if layer["inbound_nodes"] else []
        weights = dict(model.weights.get(name, []))
        if kind == "InputLayer":
            value = feeds[name]
        elif kind == "ZeroPadding2D":
            (top, bottom), (left, right) = config["padding"]
            value = np.pad(inbound[0], ((top, bottom), (left, right), (0, 0)))
        elif kind in ("Conv2D", "MaxPooling2D"):
            x = inbound[0]
            kh, kw = config["kernel_size"] if kind == "Conv2D" else config["pool_size"]
            sy, sx = config["strides"]
            oh, ow = (x.shape[0] - kh) // sy + 1, (x.shape[1] - kw) // sx + 1
            windows = np.stack([x[ky:ky + sy * oh:sy, kx:kx + sx * ow:sx] for ky in range(kh) for kx in range(kw)])
            if kind == "MaxPooling2D":
                value = windows.max(axis=0)
            else:
                kernel = weights["kernel"].reshape(kh * kw, x.shape[2], -1)
                value = np.einsum("thwc,tco->hwo", windows, kernel) + weights.get("bias", 0)
        elif kind == "Flatten":
            value = inbound[0].reshape(-1)
        elif kind == "Concatenate":
            value = np.concatenate(inbound)
        elif kind == "Dense":
            value = inbound[0] @ weights["kernel"] + weights.get("bias", 0)
        else:
            raise AssertionError(f"no reference for {kind}")
        if config.get("activation") == "relu":
            value = np.maximum(value, 0)
        values[name] = value.astype(np.float64)
    return np.concatenate([values[o].reshape(-1) for o in outputs])


def test_the_keras_model_computes_what_the_onnx_network_computes():
    model, outputs = compiled_nn.keras_from_onnx(FIXTURE)
    kinds = [layer["class_name"] for layer in model.layers]
    # Symmetric pads as their own layer before a valid convolution (Keras' `same` would pad a
    # stride-2 layer differently from PyTorch), the ReLUs folded into the layers before them.
    assert kinds.count("ZeroPadding2D") == kinds.count("Conv2D") == 4
    assert all(layer["config"]["padding"] == "valid" for layer in model.layers if layer["class_name"] == "Conv2D")
    assert "Activation" not in kinds
    session = ort.InferenceSession(str(FIXTURE), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(7)
    for _ in range(3):
        feeds = {spec.name: rng.random(spec.shape).astype(np.float32) for spec in session.get_inputs()}
        expected = session.run(None, feeds)[0].reshape(-1)
        channels_last = {name: value[0].transpose(1, 2, 0) for name, value in feeds.items()}
        got = keras_forward(model, outputs, channels_last)
        np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-5)


def test_the_first_dense_layer_is_reordered_for_channels_last_flattening():
    # Without the reordering the commands differ: the check above would fail on a plain copy.
    model, outputs = compiled_nn.keras_from_onnx(FIXTURE)
    dense = next(layer["name"] for layer in model.layers if layer["class_name"] == "Dense")
    kernel = dict(model.weights[dense])["kernel"]
    import onnx
    from onnx import numpy_helper

    graph = onnx.load(str(FIXTURE)).graph
    gemm = next(node for node in graph.node if node.op_type == "Gemm")
    onnx_weight = next(numpy_helper.to_array(i) for i in graph.initializer if i.name == gemm.input[1])
    assert kernel.shape == onnx_weight.T.shape
    assert not np.array_equal(kernel, onnx_weight.T)
    assert np.array_equal(np.sort(kernel, axis=None), np.sort(onnx_weight, axis=None))


def test_an_operator_without_a_keras_layer_is_refused(tmp_path):
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        [helper.make_node("Sigmoid", ["top"], ["command"])], "g",
        [helper.make_tensor_value_info("top", TensorProto.FLOAT, [1, 1, 4, 4])],
        [helper.make_tensor_value_info("command", TensorProto.FLOAT, [1, 1, 4, 4])])
    path = tmp_path / "policy.onnx"
    onnx.save(helper.make_model(graph), str(path))
    with pytest.raises(compiled_nn.Unsupported, match="Sigmoid"):
        compiled_nn.keras_from_onnx(path)


def test_the_keras_file_holds_the_layout_compiled_nns_reader_walks(tmp_path):
    h5py = pytest.importorskip("h5py")  # installed by scripts/setup --compiled-nn only
    path = tmp_path / "fixture.h5"
    compiled_nn.export(FIXTURE.parent, path)
    with h5py.File(path, "r") as f:
        assert f.attrs["keras_version"].startswith("2.")
        config = json.loads(f.attrs["model_config"])
        assert config["class_name"] == "Functional"
        conv = next(layer["name"] for layer in config["config"]["layers"] if layer["class_name"] == "Conv2D")
        names = [n.decode() for n in f["model_weights"][conv].attrs["weight_names"]]
        assert names == [f"{conv}/kernel:0", f"{conv}/bias:0"]
        assert f["model_weights"][conv][conv]["kernel:0"].shape[:2] == (5, 5)


def test_the_page_reads_the_rows_and_names_where_compiled_nn_is_faster():
    result = {
        "cpu": "a CPU", "steps": 10, "method": "m",
        "rows": [{"network": "narrow", "engines": [
            {"isa": "sse4.2", "compiled_nn_us": 80.0, "dribble_us": 100.0, "compiled_nn_instructions": 10,
             "dribble_instructions": 20, "compiled_nn_vs_onnxruntime": {"equal": True, "max_abs_difference": 1e-7, "cases": 8}},
            {"isa": "ssse3", "int8": True, "dribble_us": 50.0},
        ]}],
    }
    lines = compiled_nn_report.table(result)
    assert any("| narrow | sse4.2 | 80 | 100 | 0.80 |" in line for line in lines)
    verdicts = " ".join(compiled_nn_report.verdicts(result))
    assert "slower than CompiledNN on: narrow (sse4.2)" in verdicts
    assert "faster than CompiledNN's fastest float pass on every int8 row" in verdicts


def test_onnxruntime_stands_beside_our_widest_set_and_a_slower_row_is_named():
    result = {
        "cpu": "a CPU", "steps": 10, "method": "m", "onnxruntime": "onnxruntime 1.0",
        "rows": [{"network": "host model", "policy": "models/policy/some-host", "engines": [
            {"isa": "ssse3", "compiled_nn_us": 90.0, "dribble_us": 80.0},
            {"isa": "avx2+fma", "compiled_nn_us": 60.0, "dribble_us": 40.0},
            {"isa": "avx2+fma", "int8": True, "dribble_us": 35.0},
        ], "onnxruntime": {"float_us": 50.0, "int8_us": 30.0}}],
    }
    lines = compiled_nn_report.onnxruntime_table(result)
    assert "| host model (`some-host`) | 50 | 40 | 30 | 35 |" in lines
    verdicts = " ".join(compiled_nn_report.onnxruntime_verdicts(result))
    assert "not faster than onnxruntime on: host model (int8)" in verdicts
    result["rows"][0]["onnxruntime"]["int8_us"] = 36.0
    assert compiled_nn_report.onnxruntime_verdicts(result) == [
        "Our engine is faster than onnxruntime on every network, float and int8."]
