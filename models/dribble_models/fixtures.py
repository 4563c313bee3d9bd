"""Writes the committed test fixtures: one policy of each kind with seeded random weights, its
`policy.toml`, and reference inputs and outputs that the Rust runtime must reproduce; plus a
tiny policy that answers NaN, for the controller's fault handling.

    python -m dribble_models.fixtures [--out models/fixtures]

Weights are PyTorch's initialisation under a fixed seed, rounded to bfloat16 precision so the
files compress in the repository (the arithmetic stays f32). The fixture H-CNN has K = 2
networks, set in its manifest, to keep the files small and to exercise a K other than 4.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import TensorProto, helper

from . import contract
from .export import export_policy
from .gating import fit_centroids, gating_feature
from .manifest import Manifest, TrainingRecord
from .networks import CNN, HCNN, RCNN, PreviousCommandCNN, to_network_input

SEED = 2017
CNN_STEPS = 12
HCNN_STEPS = 24
RCNN_STEPS = 60
HCNN_CLUSTERS = 2
LIGHTING_GAINS = (0.35, 0.65, 0.9, 1.15)


def synthetic_pair(rng: np.random.Generator, lighting: int) -> tuple[np.ndarray, np.ndarray]:
    """A pair of thumbnails that looks vaguely like a field under one of four lightings:
    walls above a horizon, green field below, a line, a ball. Smooth, so it compresses."""
    gain = LIGHTING_GAINS[lighting] * rng.uniform(0.92, 1.08)

    def scene(shape: tuple[int, int], horizon: int) -> np.ndarray:
        height, width = shape
        y, x = np.mgrid[0:height, 0:width].astype(np.float32)
        image = np.where(y < horizon, 190.0 - 0.4 * y, 105.0 + 0.1 * (y - horizon))
        line_row = rng.integers(horizon, height) if horizon < height else height
        image = np.where(np.abs(y - line_row - 0.15 * (x - width / 2)) < height / 60 + 0.6, 235.0, image)
        cx, cy, r = rng.uniform(0, width), rng.uniform(horizon, height), rng.uniform(2, height / 8)
        image = np.where((x - cx) ** 2 + (y - cy) ** 2 < r * r, 245.0, image)
        return np.clip(image * gain, 0, 255).astype(np.uint8)

    top = scene(contract.TOP_SHAPE, int(rng.integers(10, 80)))
    bottom = scene(contract.BOTTOM_SHAPE, int(rng.integers(-10, 10)))
    return top, bottom


def synthetic_pairs(rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
    pairs = [synthetic_pair(rng, int(rng.integers(0, len(LIGHTING_GAINS)))) for _ in range(count)]
    return np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])


def round_to_bfloat16(model: torch.nn.Module) -> None:
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.copy_(parameter.to(torch.bfloat16).to(torch.float32))


def write_reference(directory: Path, tops: np.ndarray, bottoms: np.ndarray, commands: np.ndarray, **extra) -> None:
    reference = directory / "reference"
    reference.mkdir(parents=True, exist_ok=True)
    interleaved = np.concatenate([tops.reshape(len(tops), -1), bottoms.reshape(len(bottoms), -1)], axis=1)
    interleaved.astype(np.uint8).tofile(reference / "thumbnails.u8")
    commands.astype("<f4").tofile(reference / "commands.f32")
    lines = [
        "# Reference steps: thumbnails.u8 holds, per step, the 120x160 top then the 60x80",
        "# bottom thumbnail (u8, row-major); commands.f32 the 3 outputs per step (f32, LE),",
        "# as PyTorch computed them. R-CNN steps run in order from a zero state.",
        f"steps = {len(tops)}",
    ]
    lines += [f"{key} = {value!r}".replace("'", '"') for key, value in extra.items()]
    (reference / "reference.toml").write_text("\n".join(lines) + "\n")


def fixture_record() -> TrainingRecord:
    return TrainingRecord(dataset=f"none: seeded random weights (fixture, seed {SEED})", epochs=0)


def write_cnn(out: Path, rng: np.random.Generator) -> None:
    torch.manual_seed(SEED)
    model = CNN().eval()
    round_to_bfloat16(model)
    export_policy(model, out / "cnn", fixture_record())
    tops, bottoms = synthetic_pairs(rng, CNN_STEPS)
    with torch.no_grad():
        commands = model(*to_network_input(tops, bottoms)).numpy()
    write_reference(out / "cnn", tops, bottoms, commands)


def write_hcnn(out: Path, rng: np.random.Generator) -> None:
    train_tops, train_bottoms = synthetic_pairs(rng, 200)
    features = np.stack([gating_feature(t, b) for t, b in zip(train_tops, train_bottoms)])
    centroids = fit_centroids(features, HCNN_CLUSTERS, seed=SEED)
    torch.manual_seed(SEED + 1)
    model = HCNN(centroids).eval()
    round_to_bfloat16(model)
    export_policy(model, out / "hcnn", fixture_record())
    tops, bottoms = synthetic_pairs(rng, HCNN_STEPS)
    commands, clusters = [], []
    with torch.no_grad():
        for top, bottom in zip(tops, bottoms):
            command, cluster = model.forward_u8(top, bottom)
            commands.append(command.numpy()[0])
            clusters.append(cluster)
    assert len(set(clusters)) == HCNN_CLUSTERS, f"reference steps must visit every network, got {clusters}"
    write_reference(out / "hcnn", tops, bottoms, np.stack(commands), clusters=clusters)


def write_rcnn(out: Path, rng: np.random.Generator) -> None:
    torch.manual_seed(SEED + 2)
    model = RCNN().eval()
    round_to_bfloat16(model)
    export_policy(model, out / "rcnn", fixture_record())
    tops, bottoms = synthetic_pairs(rng, RCNN_STEPS)
    top, bottom = to_network_input(tops, bottoms)
    with torch.no_grad():
        commands, _ = model(top.unsqueeze(0), bottom.unsqueeze(0))
    write_reference(out / "rcnn", tops, bottoms, commands[0].numpy())


def write_cnn_previous(out: Path, rng: np.random.Generator) -> None:
    """A CNN that also reads the last command sent (`[inputs] previous`), with a reference:
    per step the thumbnails, the last command fed (`previous.f32`, 3 f32 per step: a stop at
    the first step, then commands across the whole range) and PyTorch's command."""
    torch.manual_seed(SEED + 3)
    model = PreviousCommandCNN().eval()
    with torch.no_grad():
        # Weights of a trained network's size on the last command, so its effect is plain.
        model.hidden.weight[:, -3:] = torch.randn(model.hidden.out_features, 3) * 0.5
    round_to_bfloat16(model)
    export_policy(model, out / "cnn-previous", fixture_record())
    tops, bottoms = synthetic_pairs(rng, CNN_STEPS)
    previous = rng.uniform(-1.0, 1.0, size=(CNN_STEPS, 3)).astype(np.float32)
    previous[0] = 0.0
    with torch.no_grad():
        commands = model(*to_network_input(tops, bottoms), torch.from_numpy(previous)).numpy()
    write_reference(out / "cnn-previous", tops, bottoms, commands)
    previous.astype("<f4").tofile(out / "cnn-previous" / "reference" / "previous.f32")


CNN_INT8_CALIBRATION = 48
CNN_INT8_REFERENCE_STEPS = 4


def write_cnn_int8(out: Path, rng: np.random.Generator) -> None:
    """The fixture CNN quantized to int8 (QDQ) by `dribble_models.quantize`, calibrated on
    synthetic frames (a fixture has no training episodes), with its own reference: what
    onnxruntime computes from the int8 file on the CNN fixture's reference thumbnails."""
    import hashlib

    import onnxruntime as ort

    from .quantize import write_int8_policy

    tops, bottoms = synthetic_pairs(rng, CNN_INT8_CALIBRATION)
    scale = np.float32(contract.INPUT_SCALE)
    feeds = [
        {contract.TOP_INPUT: t[None, None].astype(np.float32) * scale, contract.BOTTOM_INPUT: b[None, None].astype(np.float32) * scale}
        for t, b in zip(tops, bottoms)
    ]
    rows = [(0, i) for i in range(len(feeds))]
    calibration = {
        "calibration_dataset_hash": hashlib.sha256(tops.tobytes() + bottoms.tobytes()).hexdigest(),
        "calibration_frames": len(rows),
        "calibration_seed": SEED,
        "calibration_rows_sha256": hashlib.sha256(str(rows).encode()).hexdigest(),
    }
    write_int8_policy(out / "cnn", out / "cnn-int8", [feeds], calibration)
    reference = np.fromfile(out / "cnn" / "reference" / "thumbnails.u8", np.uint8)
    top_size, bottom_size = np.prod(contract.TOP_SHAPE), np.prod(contract.BOTTOM_SHAPE)
    steps = reference.reshape(-1, top_size + bottom_size)
    steps = steps[:CNN_INT8_REFERENCE_STEPS]
    ref_tops = steps[:, :top_size].reshape(-1, *contract.TOP_SHAPE)
    ref_bottoms = steps[:, top_size:].reshape(-1, *contract.BOTTOM_SHAPE)
    session = ort.InferenceSession(str(out / "cnn-int8" / "policy.onnx"), providers=["CPUExecutionProvider"])
    commands = np.stack(
        [
            session.run(
                [contract.COMMAND_OUTPUT],
                {contract.TOP_INPUT: t[None, None].astype(np.float32) * scale, contract.BOTTOM_INPUT: b[None, None].astype(np.float32) * scale},
            )[0][0]
            for t, b in zip(ref_tops, ref_bottoms)
        ]
    )
    write_reference(out / "cnn-int8", ref_tops, ref_bottoms, commands)


def write_nan(out: Path) -> None:
    """A model with the CNN's inputs and output that answers NaN for forward: built node by
    node, a few hundred bytes."""
    directory = out / "nan"
    directory.mkdir(parents=True, exist_ok=True)
    top = helper.make_tensor_value_info(contract.TOP_INPUT, TensorProto.FLOAT, [1, 1, *contract.TOP_SHAPE])
    bottom = helper.make_tensor_value_info(contract.BOTTOM_INPUT, TensorProto.FLOAT, [1, 1, *contract.BOTTOM_SHAPE])
    command = helper.make_tensor_value_info(contract.COMMAND_OUTPUT, TensorProto.FLOAT, [1, 3])
    nodes = [
        helper.make_node("ReduceMean", ["top"], ["top_mean"], axes=[2, 3], keepdims=0),
        helper.make_node("ReduceMean", ["bottom"], ["bottom_mean"], axes=[2, 3], keepdims=0),
        helper.make_node("Add", ["top_mean", "bottom_mean"], ["brightness"]),
        helper.make_node("Mul", ["brightness", "poison"], [contract.COMMAND_OUTPUT]),
    ]
    poison = helper.make_tensor("poison", TensorProto.FLOAT, [1, 3], [float("nan"), 0.0, 0.5])
    graph = helper.make_graph(nodes, "nan_policy", [top, bottom], [command], initializer=[poison])
    # IR version 8 is the one that goes with opset 17, as the exporter writes it.
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", contract.OPSET)], ir_version=8)
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, directory / "policy.onnx")
    record = TrainingRecord(dataset="none: hand-built model whose forward output is NaN (fixture)", epochs=0)
    Manifest("cnn", ["policy.onnx"], record).write(directory)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "fixtures")
    args = parser.parse_args()
    rng = np.random.default_rng(SEED)
    write_cnn(args.out, rng)
    write_hcnn(args.out, rng)
    write_rcnn(args.out, rng)
    write_nan(args.out)
    # Its own generator, so that the other fixtures stay what they were before it existed.
    write_cnn_int8(args.out, np.random.default_rng(SEED + 8))
    write_cnn_previous(args.out, np.random.default_rng(SEED + 9))
    for path in sorted(args.out.rglob("*")):
        if path.is_file():
            print(f"{path.stat().st_size:>9}  {path.relative_to(args.out)}")


if __name__ == "__main__":
    main()
