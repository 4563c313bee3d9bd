"""Post-training static quantization of a shipped policy to int8 (issue 29; DESIGN.md,
"Policies", `precision`).

    python -m dribble_models.quantize --policy models/policy/cnn-observable \\
        --dataset ~/.cache/dribble/data-observable/train --out models/policy/cnn-observable-int8

What it does, and why each choice:

- onnxruntime's own static quantizer (`quantize_static`) in the QDQ format writes the int8
  network: every quantized tensor is a `QuantizeLinear`/`DequantizeLinear` pair in an
  ordinary ONNX file, so one file is at once what the controller runs (its engine lowers the
  pairs to integer kernels; tract runs the same file where the engine cannot), the oracle
  (onnxruntime runs it) and the side-by-side peer of the benchmarks.
- Hidden layers in int8, output layers in float: every `Conv`, and every `Gemm` whose output
  goes through a `Relu`; a `Gemm` that makes the command (or the hypotheses and the choice of
  the two-hypothesis CNN) stays float, as the LSTM does. These are a few hundred
  multiply-adds of the 6.6 M; their rounding would go straight into the command.
- Weights int8 per output channel (symmetric), activations uint8 per tensor (MinMax over
  the calibration frames). Weights use 7 bits (`reduce_range`: -64..64): SSSE3's
  `pmaddubsw` adds two u8 x s8 products in 16 bits with saturation, and 2 x 255 x 64 =
  32,640 fits where 2 x 255 x 127 would not, so the integer kernels are exact.
- Calibration frames come from the policy's own training dataset (its content hash must be
  the manifest's `[training] dataset_hash`), from episodes it fitted on (the validation
  seeds are left out), drawn with a seed; never from a test or selection seed. The R-CNN's
  frames come with the LSTM state the float network carries to them, from an episode's
  start. The manifest records precision, the quantizer, the scales and a hash of exactly
  which rows calibrated it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import numpy_helper
from onnxruntime.quantization import (
    CalibrationDataReader,
    CalibrationMethod,
    QuantFormat,
    QuantType,
    quantize_static,
)

from . import contract, dataset
from .gating import nearest_cluster
from .manifest import load as load_manifest
from .seed_ranges import ReservedSeedError, refuse_reserved

# What the manifest says about the method, for a reader of the file.
METHOD = "onnxruntime quantize_static, QDQ; weights int8 per output channel, 7 bits (reduce_range); activations uint8 per tensor, MinMax"
WEIGHT_BITS = 7


class QuantizeError(Exception):
    """A policy or dataset that cannot be quantized as asked."""


def hidden_layers(model: onnx.ModelProto) -> list[str]:
    """The nodes to quantize: every Conv, and every Gemm whose output feeds a Relu."""
    consumers: dict[str, list[str]] = {}
    for node in model.graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node.op_type)
    chosen = []
    for node in model.graph.node:
        if node.op_type == "Conv":
            chosen.append(node.name)
        elif node.op_type == "Gemm" and "Relu" in consumers.get(node.output[0], []):
            chosen.append(node.name)
    return chosen


# The training episodes' seeds (`dribble record`'s training range; the test seeds start at 10000).
TRAINING_SEEDS = range(0, 100)


def check_calibration_dataset(train: dataset.Dataset, training: dict, directory: Path, policy: Path) -> None:
    """Calibration sees training episodes only: the policy's own training dataset (by content
    hash), or episodes re-recorded from its training seeds by the same teacher (recording is
    deterministic per seed), none of them a validation seed. Anything else is refused, and
    first of all any episode of the seeds kept for choosing and reporting (`seed_ranges`)."""
    try:
        refuse_reserved(train.seeds(), str(directory), use="calibration")
    except ReservedSeedError as error:
        raise QuantizeError(str(error)) from error
    if training.get("dataset_hash") == train.content_hash:
        return
    teacher = training.get("teacher", "paper")
    validation = set(training.get("validation_seeds", []))
    outside = [s for s in train.seeds() if s not in TRAINING_SEEDS or s in validation]
    if train.teacher != teacher or outside:
        raise QuantizeError(
            f"{directory} (content hash {train.content_hash[:12]}, teacher {train.teacher}) is neither the dataset "
            f"{policy} was trained on ({str(training.get('dataset_hash'))[:12]}) nor episodes of its training seeds "
            f"recorded by its teacher ({teacher})"
            + (f": seeds {outside[:5]} are not training seeds" if outside else "")
            + "; calibration uses training episodes only"
        )


def calibration_rows(train: dataset.Dataset, frames: int, seed: int, exclude_seeds: set[int]) -> list[tuple[int, int]]:
    """(episode seed, row) pairs drawn without replacement, in a fixed order."""
    rows = [(e.seed, t) for e in train.episodes if e.seed not in exclude_seeds for t in range(len(e))]
    if not rows:
        raise QuantizeError(f"{train.directory}: no training rows outside the validation seeds")
    rng = np.random.default_rng(seed)
    picked = rng.choice(len(rows), size=min(frames, len(rows)), replace=False)
    return sorted(rows[i] for i in picked)


def rows_hash(rows: list[tuple[int, int]]) -> str:
    return hashlib.sha256(json.dumps(rows).encode()).hexdigest()


def _inputs(episode: dataset.Episode, t: int, standardise: bool, previous: bool = False) -> dict[str, np.ndarray]:
    """What the controller feeds the network at row `t` (`contract.network_input`), and for a
    network that reads it the command executed at the row before (`Episode.previous`)."""
    feed = {
        contract.TOP_INPUT: contract.network_input(episode.top[t][None, None], standardise),
        contract.BOTTOM_INPUT: contract.network_input(episode.bottom[t][None, None], standardise),
    }
    if previous:
        feed[contract.PREVIOUS_INPUT] = episode.previous[t][None].astype(np.float32)
    return feed


class Frames(CalibrationDataReader):
    """The calibration feeds, computed once."""

    def __init__(self, feeds: list[dict[str, np.ndarray]]):
        self.feeds = feeds
        self.position = 0

    def get_next(self) -> dict[str, np.ndarray] | None:
        if self.position >= len(self.feeds):
            return None
        self.position += 1
        return self.feeds[self.position - 1]

    def rewind(self) -> None:
        self.position = 0


def feeds_for(kind: str, network: Path, train: dataset.Dataset, rows: list[tuple[int, int]], units: int, standardise: bool = False, previous: bool = False) -> list[dict]:
    """Each row's network inputs; the R-CNN's with the state its float network carries there."""
    by_seed = {e.seed: e for e in train.episodes}
    if kind != "rcnn":
        return [_inputs(by_seed[s], t, standardise, previous) for s, t in rows]
    session = ort.InferenceSession(str(network), providers=["CPUExecutionProvider"])
    wanted: dict[int, set[int]] = {}
    for s, t in rows:
        wanted.setdefault(s, set()).add(t)
    feeds = []
    for s in sorted(wanted):
        episode = by_seed[s]
        h = np.zeros((1, 1, units), np.float32)
        c = np.zeros((1, 1, units), np.float32)
        for t in range(max(wanted[s]) + 1):
            feed = _inputs(episode, t, standardise) | {contract.H_INPUT: h, contract.C_INPUT: c}
            if t in wanted[s]:
                feeds.append(dict(feed))
            _, h, c = session.run([contract.COMMAND_OUTPUT, contract.H_OUTPUT, contract.C_OUTPUT], feed)
    return feeds


def activation_scales(model: onnx.ModelProto) -> dict[str, float]:
    """The scale of every activation QuantizeLinear, by the tensor it quantizes."""
    initialisers = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    scales = {}
    for node in model.graph.node:
        if node.op_type == "QuantizeLinear" and node.input[1] in initialisers:
            scales[node.input[0]] = float(initialisers[node.input[1]])
    return scales


def quantize_network(source: Path, target: Path, feeds: list[dict]) -> dict[str, float]:
    model = onnx.load(str(source))
    nodes = hidden_layers(model)
    if not nodes:
        raise QuantizeError(f"{source}: no Conv or hidden Gemm to quantize")
    quantize_static(
        str(source),
        str(target),
        Frames(feeds),
        quant_format=QuantFormat.QDQ,
        per_channel=True,
        reduce_range=True,
        activation_type=QuantType.QUInt8,
        weight_type=QuantType.QInt8,
        nodes_to_quantize=nodes,
        calibrate_method=CalibrationMethod.MinMax,
    )
    quantized = onnx.load(str(target))
    onnx.checker.check_model(quantized, full_check=True)
    check_weight_range(quantized)
    return activation_scales(quantized)


def check_weight_range(model: onnx.ModelProto) -> None:
    """Every int8 weight within -64..64 (onnxruntime's `reduce_range` maps the largest
    magnitude to 64), as the integer kernels need: 2 x 255 x 64 = 32,640 fits in 16 bits."""
    limit = 2 ** (WEIGHT_BITS - 1)
    for initialiser in model.graph.initializer:
        if initialiser.data_type == onnx.TensorProto.INT8:
            values = numpy_helper.to_array(initialiser)
            if values.size and (values.min() < -limit or values.max() > limit):
                raise QuantizeError(f"{initialiser.name}: int8 weights outside {-limit}..{limit}")


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def quantization_toml(record: dict) -> str:
    lines = [
        "",
        "# Post-training static quantization (dribble_models.quantize): what made the int8 file.",
        "[quantization]",
        f'method = "{METHOD}"',
        f"weight_bits = {WEIGHT_BITS}",
        f'onnxruntime_version = "{record["onnxruntime_version"]}"',
        f'float_networks_sha256 = [{", ".join(json.dumps(h) for h in record["float_networks_sha256"])}]',
        f'calibration_dataset_hash = "{record["calibration_dataset_hash"]}"',
        f"calibration_frames = {record['calibration_frames']}",
        f"calibration_seed = {record['calibration_seed']}",
        f'calibration_rows_sha256 = "{record["calibration_rows_sha256"]}"',
    ]
    for index, scales in enumerate(record["activation_scales"]):
        entries = ", ".join(f"{json.dumps(name)} = {float(scale)!r}" for name, scale in sorted(scales.items()))
        lines.append(f"[[quantization.networks]]\nnetwork = {json.dumps(record['networks'][index])}")
        lines.append(f"activation_scales = {{ {entries} }}")
    return "\n".join(lines) + "\n"


def with_precision(manifest_text: str, precision: str) -> str:
    """The manifest with `precision = ...` after its `networks` line, without the float
    model's former names (its lineage's other lines describe the int8 weights too)."""
    out = []
    for line in manifest_text.splitlines():
        if line.startswith("precision =") or line.startswith("former_names ="):
            continue
        out.append(line)
        if line.startswith("networks ="):
            out.append(f'precision = "{precision}"')
    return "\n".join(out) + "\n"


def write_int8_policy(policy: Path, out: Path, feeds: list[list[dict]], calibration: dict) -> dict:
    """Quantizes each network of the float policy in `policy` on its calibration feeds (one
    list per network, in `networks` order) into `out`, with the manifest saying
    `precision = "int8"` and the `[quantization]` record (`calibration`: the
    calibration_dataset_hash, _frames, _seed and _rows_sha256 fields). Returns the record."""
    policy, out = Path(policy), Path(out)
    manifest = load_manifest(policy / "policy.toml")
    if manifest.get("precision", "fp32") != "fp32":
        raise QuantizeError(f"{policy}: already {manifest['precision']}")
    networks = manifest["networks"]
    out.mkdir(parents=True, exist_ok=True)
    scales = []
    for name, network_feeds in zip(networks, feeds, strict=True):
        with tempfile.TemporaryDirectory() as scratch:
            # The quantizer writes beside its input; work on a copy.
            source = Path(scratch) / name
            shutil.copy(policy / name, source)
            scales.append(quantize_network(source, out / name, network_feeds))
    record = {
        "onnxruntime_version": ort.__version__,
        "float_networks_sha256": [_sha256(policy / n) for n in networks],
        **calibration,
        "activation_scales": scales,
        "networks": networks,
    }
    text = with_precision((policy / "policy.toml").read_text(), "int8") + quantization_toml(record)
    (out / "policy.toml").write_text(text)
    return record


def quantize_policy(policy: Path, train_dir: Path, out: Path, frames: int = 256, seed: int = 0) -> dict:
    """Writes the int8 policy into `out` and returns its quantization record."""
    policy, out = Path(policy), Path(out)
    manifest = load_manifest(policy / "policy.toml")
    training = manifest.get("training", {})
    train = dataset.load(train_dir)
    validation = set(training.get("validation_seeds", []))
    check_calibration_dataset(train, training, train_dir, policy)
    rows = calibration_rows(train, frames, seed, validation)
    kind = manifest["kind"]
    units = manifest.get("recurrent", {}).get("units", contract.LSTM_UNITS)
    by_seed = {e.seed: e for e in train.episodes}
    feeds = []
    for index, name in enumerate(manifest["networks"]):
        network_rows = rows
        if kind == "hcnn":
            # Each expert calibrated on the frames its gate sends it, where there are some.
            centroids = np.asarray(manifest["gating"]["centroids"], np.float32)
            routed = [(s, t) for s, t in rows if nearest_cluster(by_seed[s].top[t], by_seed[s].bottom[t], centroids) == index]
            network_rows = routed if len(routed) >= 16 else rows
        standardise = bool(manifest.get("normalisation", {}).get("standardise", False))
        previous = "previous" in manifest.get("inputs", {})
        feeds.append(feeds_for(kind, policy / name, train, network_rows, units, standardise, previous))
    calibration = {
        "calibration_dataset_hash": train.content_hash,
        "calibration_frames": len(rows),
        "calibration_seed": seed,
        "calibration_rows_sha256": rows_hash(rows),
    }
    return write_int8_policy(policy, out, feeds, calibration)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dribble_models.quantize",
        description="Post-training static int8 quantization of a policy (QDQ ONNX), calibrated on its own training episodes.",
    )
    parser.add_argument("--policy", type=Path, required=True, help="the float policy's directory (policy.toml and its networks)")
    parser.add_argument("--dataset", type=Path, required=True, help="the dataset it was trained on (checked by content hash)")
    parser.add_argument("--out", type=Path, required=True, help="where the int8 policy goes")
    parser.add_argument("--frames", type=int, default=256, help="calibration frames (default 256)")
    parser.add_argument("--seed", type=int, default=0, help="which frames (default 0)")
    args = parser.parse_args(argv)
    start = time.monotonic()
    try:
        record = quantize_policy(args.policy, args.dataset, args.out, args.frames, args.seed)
    except (QuantizeError, dataset.DatasetError) as error:
        print(f"quantize: {error}", file=sys.stderr)
        return 2
    print(
        f"quantize: {args.out} from {args.policy}: {record['calibration_frames']} calibration frames "
        f"(rows sha256 {record['calibration_rows_sha256'][:12]}), {time.monotonic() - start:.1f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
