"""B-Human's CompiledNN beside dribble's engine on the same networks (issue 49): the engine
SPL teams run on the Nao (B-Human's code; HULKs' through the `compiled-nn` crate).

    python -m dribble_models.compiled_nn export POLICY_DIR OUT.h5
    python -m dribble_models.compiled_nn compare [--steps 2000] [--out models/performance/compiled-nn.json]

CompiledNN reads Keras 2 HDF5 files only: the ONNX reader its sources carry (0.12.0) parses
the protobuf and then fails with "Not yet implemented". `export` therefore writes a policy's
ONNX CNN as the Keras functional model that computes the same function, channels last:

- each `Conv` with its symmetric pads becomes `ZeroPadding2D` + a `valid` `Conv2D` (Keras'
  `same` pads a stride-2 layer one pixel less on the left than PyTorch's `padding=2`, so it
  would be a different network), the `Relu` after it folded in as its activation;
- `MaxPool`, `Flatten`, `Concat` map one to one; `Gemm` becomes `Dense`, its columns
  reordered from the channels-first flattening ONNX saw to the channels-last one Keras does.

`compare` runs, one thread, one process after the other on this machine: CompiledNN's
forward (benches/compiled_nn/compiled_nn_forward.cpp) and `dribble-controller forward` on
each network and instruction set, the int8 twins on ours, the medians of `--steps` passes,
the instructions of one pass under callgrind (`--steps 11` minus `--steps 1`, over ten, as
`cross/count` counts), and whether CompiledNN's command equals onnxruntime's on real-looking
inputs (the check that the exported file is the same network; dribble's engine is held to
tract by its own parity tests); and onnxruntime's step on each network and int8 twin
(`ort_bench`, one thread), which picks its kernels from the CPU and so stands beside our
widest set. The machine must be built with `scripts/setup --compiled-nn`.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import re
import statistics
import subprocess
import sys
import tempfile

import numpy as np
import onnx
from onnx import helper, numpy_helper

from . import contract
from . import manifest as policy_manifest
from .cluster import binary_dir

ROOT = pathlib.Path(__file__).resolve().parents[2]
PREFIX = pathlib.Path(os.environ.get("DRIBBLE_COMPILED_NN", pathlib.Path.home() / ".cache/dribble/compiled-nn"))
KERAS_VERSION = "2.4.0"  # the newest layout CompiledNN's reader knows (it refuses Keras 3)
ISAS = ("ssse3", "sse4.2", "avx2+fma")


class Unsupported(Exception):
    """The ONNX graph holds something the export does not map to a Keras layer."""


def _attributes(node) -> dict:
    return {a.name: helper.get_attribute_value(a) for a in node.attribute}


class KerasModel:
    """A Keras 2 functional model built layer by layer from an ONNX graph."""

    def __init__(self, name: str):
        self.name = name
        self.layers: list[dict] = []
        self.weights: dict[str, list[tuple[str, np.ndarray]]] = {}
        self.inputs: list[str] = []

    def add(self, class_name: str, config: dict, inbound: list[str], weights=None) -> str:
        name = f"{class_name.lower()}_{len(self.layers)}"
        config = {"name": name, "trainable": True, "dtype": "float32", **config}
        nodes = [[[source, 0, 0, {}] for source in inbound]] if inbound else []
        self.layers.append({"class_name": class_name, "config": config, "name": name, "inbound_nodes": nodes})
        if weights:
            self.weights[name] = weights
        return name

    def add_input(self, name: str, shape_hwc: list[int]) -> str:
        config = {"batch_input_shape": [None, *shape_hwc], "dtype": "float32", "sparse": False,
                  "ragged": False, "name": name}
        self.layers.append({"class_name": "InputLayer", "config": config, "name": name, "inbound_nodes": []})
        self.inputs.append(name)
        return name

    def config(self, outputs: list[str]) -> str:
        return json.dumps({
            "class_name": "Functional",
            "config": {
                "name": self.name,
                "layers": self.layers,
                "input_layers": [[name, 0, 0] for name in self.inputs],
                "output_layers": [[name, 0, 0] for name in outputs],
            },
            "keras_version": KERAS_VERSION,
            "backend": "tensorflow",
        })


def keras_from_onnx(path: pathlib.Path) -> tuple[KerasModel, list[str]]:
    """The Keras model computing what the ONNX CNN at `path` computes, and its output layers."""
    graph = onnx.load(str(path)).graph
    initial = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    model = KerasModel(path.parent.name or "policy")
    # Per ONNX value: its Keras layer, and for a flat vector the permutation that maps
    # Keras' channels-last positions to ONNX's channels-first ones; for a 4-d one (C, H, W).
    layer_of: dict[str, str] = {}
    shape_of: dict[str, tuple[int, int, int]] = {}
    order_of: dict[str, np.ndarray] = {}
    for value in graph.input:
        if value.name in initial:
            continue
        dims = [d.dim_value for d in value.type.tensor_type.shape.dim]
        if len(dims) != 4:
            raise Unsupported(f"input {value.name} has shape {dims}, not (1, C, H, W)")
        _, c, h, w = dims
        layer_of[value.name] = model.add_input(value.name, [h, w, c])
        shape_of[value.name] = (c, h, w)
    consumers: dict[str, list] = {}
    for node in graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    folded: set[str] = set()

    def relu_after(output: str) -> str | None:
        after = consumers.get(output, [])
        if len(after) == 1 and after[0].op_type == "Relu":
            folded.add(after[0].name or after[0].output[0])
            return after[0].output[0]
        return None

    for node in graph.node:
        key = node.name or node.output[0]
        if key in folded:
            continue
        a = _attributes(node)
        source = node.input[0]
        if node.op_type == "Conv":
            weight, bias = initial[node.input[1]], initial[node.input[2]] if len(node.input) > 2 else None
            if a.get("group", 1) != 1 or any(d != 1 for d in a.get("dilations", [1, 1])):
                raise Unsupported("grouped or dilated convolution")
            pads = a.get("pads", [0, 0, 0, 0])
            c, h, w = shape_of[source]
            inbound = layer_of[source]
            if any(pads):
                inbound = model.add("ZeroPadding2D", {"padding": [[pads[0], pads[2]], [pads[1], pads[3]]],
                                                      "data_format": "channels_last"}, [inbound])
                h, w = h + pads[0] + pads[2], w + pads[1] + pads[3]
            relu = relu_after(node.output[0])
            kernel = np.ascontiguousarray(weight.transpose(2, 3, 1, 0).astype(np.float32))  # HWIO
            weights = [("kernel", kernel)] + ([("bias", bias.astype(np.float32))] if bias is not None else [])
            stride = a.get("strides", [1, 1])
            kh, kw = a["kernel_shape"]
            name = model.add("Conv2D", {
                "filters": int(weight.shape[0]), "kernel_size": [kh, kw], "strides": stride,
                "padding": "valid", "data_format": "channels_last", "dilation_rate": [1, 1], "groups": 1,
                "activation": "relu" if relu else "linear", "use_bias": bias is not None,
            }, [inbound], weights)
            out = relu or node.output[0]
            layer_of[out] = name
            shape_of[out] = (int(weight.shape[0]), (h - kh) // stride[0] + 1, (w - kw) // stride[1] + 1)
        elif node.op_type == "MaxPool":
            if any(a.get("pads", [0, 0, 0, 0])) or a.get("ceil_mode", 0):
                raise Unsupported("padded or ceil-mode max pooling")
            c, h, w = shape_of[source]
            (kh, kw), stride = a["kernel_shape"], a.get("strides", [1, 1])
            layer_of[node.output[0]] = model.add("MaxPooling2D", {
                "pool_size": [kh, kw], "padding": "valid", "strides": stride, "data_format": "channels_last",
            }, [layer_of[source]])
            shape_of[node.output[0]] = (c, (h - kh) // stride[0] + 1, (w - kw) // stride[1] + 1)
        elif node.op_type == "Flatten":
            c, h, w = shape_of[source]
            layer_of[node.output[0]] = model.add("Flatten", {"data_format": "channels_last"}, [layer_of[source]])
            # Keras position (y, x, channel) holds ONNX position (channel, y, x).
            order_of[node.output[0]] = np.arange(c * h * w).reshape(c, h, w).transpose(1, 2, 0).reshape(-1)
        elif node.op_type == "Concat":
            if any(name not in order_of for name in node.input):
                raise Unsupported("concatenation of anything but flat vectors")
            layer_of[node.output[0]] = model.add("Concatenate", {"axis": -1}, [layer_of[n] for n in node.input])
            offsets = np.cumsum([0] + [len(order_of[n]) for n in node.input])
            order_of[node.output[0]] = np.concatenate([order_of[n] + o for n, o in zip(node.input, offsets)])
        elif node.op_type == "Gemm":
            if a.get("transA", 0) or a.get("alpha", 1.0) != 1.0 or a.get("beta", 1.0) != 1.0:
                raise Unsupported("Gemm other than x W^T + b")
            weight = initial[node.input[1]]
            weight = weight if a.get("transB", 0) else weight.T  # (out, in)
            order = order_of.get(source, np.arange(weight.shape[1]))
            relu = relu_after(node.output[0])
            weights = [("kernel", np.ascontiguousarray(weight[:, order].T.astype(np.float32)))]
            if len(node.input) > 2:
                weights.append(("bias", initial[node.input[2]].astype(np.float32)))
            out = relu or node.output[0]
            layer_of[out] = model.add("Dense", {
                "units": int(weight.shape[0]), "activation": "relu" if relu else "linear",
                "use_bias": len(node.input) > 2,
            }, [layer_of[source]], weights)
            order_of[out] = np.arange(weight.shape[0])
        else:
            raise Unsupported(f"operator {node.op_type}")
    return model, [layer_of[o.name] for o in graph.output]


def write_keras(model: KerasModel, outputs: list[str], path: pathlib.Path) -> None:
    """The Keras 2 HDF5 layout CompiledNN's reader walks: the model's JSON as the root's
    `model_config`, each layer's weights under model_weights/<layer>/<layer>/<name>:0 with
    the names in a fixed-length `weight_names` attribute."""
    import h5py

    ascii_text = h5py.string_dtype("ascii")
    with h5py.File(path, "w") as f:
        f.attrs.create("keras_version", KERAS_VERSION, dtype=ascii_text)
        f.attrs.create("backend", "tensorflow", dtype=ascii_text)
        f.attrs.create("model_config", model.config(outputs), dtype=ascii_text)
        group = f.create_group("model_weights")
        group.attrs["layer_names"] = np.array([layer["name"].encode() for layer in model.layers])
        for layer in model.layers:
            entry = group.create_group(layer["name"])
            weights = model.weights.get(layer["name"], [])
            entry.attrs["weight_names"] = np.array([f"{layer['name']}/{w}:0".encode() for w, _ in weights] or [b""])
            for weight_name, values in weights:
                entry.create_dataset(f"{layer['name']}/{weight_name}:0", data=values)


def export(policy: pathlib.Path, out: pathlib.Path) -> list[str]:
    """Writes the policy's network as a Keras 2 HDF5 file; returns its inputs' names."""
    onnx_path = policy / "policy.onnx" if policy.is_dir() else policy
    model, outputs = keras_from_onnx(onnx_path)
    write_keras(model, outputs, out)
    return model.inputs


# --- the comparison -----------------------------------------------------------------------


def _driver() -> pathlib.Path:
    driver = PREFIX / "bin" / "compiled_nn_forward"
    if not driver.exists():
        sys.exit(f"compiled_nn: {driver} is missing: run scripts/setup --compiled-nn")
    return driver


def _controller() -> pathlib.Path:
    path = binary_dir() / "dribble-controller"
    if not path.exists():
        sys.exit(f"compiled_nn: {path} is missing: cargo build --release --bin dribble-controller")
    return path


def _median_us(text: str, pattern: str) -> float:
    found = re.search(pattern, text)
    if not found:
        raise RuntimeError(f"no timing in:\n{text[-1500:]}")
    return float(found.group(1))


def _ours_us(policy: pathlib.Path, isa: str, steps: int) -> float:
    run = subprocess.run([str(_controller()), "forward", "--policy", str(policy / "policy.toml"), "--isa", isa,
                          "--steps", str(steps), "--no-peak"], capture_output=True, text=True, check=True,
                         env={**os.environ, "RUST_LOG": "warn"})
    # "median 123.4 µs" or "median 0.1234 ms"
    found = re.search(r"median\s+([0-9.]+)\s*(µs|us|ms)", run.stdout)
    if not found:
        raise RuntimeError(f"no median in dribble-controller forward's output:\n{run.stdout[-1500:]}")
    return float(found.group(1)) * (1000.0 if found.group(2) == "ms" else 1.0)


def _theirs(h5: pathlib.Path, isa: str, steps: int, inputs: pathlib.Path | None = None,
            outputs: pathlib.Path | None = None) -> float:
    command = [str(_driver()), str(h5), "--isa", isa, "--steps", str(steps)]
    if inputs:
        command += ["--inputs", str(inputs)]
    if outputs:
        command += ["--outputs", str(outputs)]
    run = subprocess.run(command, capture_output=True, text=True, check=True)
    return _median_us(run.stdout, r"median_us=([0-9.]+)")


def _instructions(command: list[str]) -> int:
    """Instructions callgrind counts for a whole run of `command`."""
    run = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", *command],
                         capture_output=True, text=True, env={**os.environ, "RUST_LOG": "warn"})
    found = re.search(r"Collected\s*:\s*(\d+)", run.stderr)
    if run.returncode != 0 or not found:
        raise RuntimeError(f"callgrind failed on {command[0]}:\n{run.stderr[-1500:]}")
    return int(found.group(1))


def _per_pass(command: list[str]) -> int:
    return round((_instructions([*command, "--steps", "11"]) - _instructions([*command, "--steps", "1"])) / 10)


def _onnxruntime_us(policy: pathlib.Path, repeats: int, steps: int) -> float:
    """onnxruntime's median step of the policy's network (`ort_bench`: one thread, random
    thumbnails), the best of `repeats` runs. It picks its kernels from the CPU: its figure
    stands beside our widest instruction set."""
    from . import ort_bench

    networks = policy_manifest.load(policy / "policy.toml").get("networks", [])
    if len(networks) != 1:
        raise SystemExit(f"compiled_nn: {policy}: {len(networks)} networks; only one-network policies compare")
    session = ort_bench.session(policy / networks[0])
    return min(statistics.median(ort_bench.time_steps(session, steps, seed)) for seed in range(repeats))


def _commands_agree(policy: pathlib.Path, h5: pathlib.Path, isa: str, cases: int = 8) -> dict:
    """CompiledNN's output against onnxruntime's on `cases` inputs (thumbnails with smooth
    structure and noise, made the network's input as the manifest's normalisation says)."""
    import onnxruntime as ort

    normalisation = policy_manifest.load(policy / "policy.toml").get("normalisation", {})
    standardise = bool(normalisation.get("standardise", False))
    scale = float(normalisation.get("scale", contract.INPUT_SCALE))
    session = ort.InferenceSession(str(policy / "policy.onnx"), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(49)
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(cases):
            feeds, flat = {}, []
            for spec in session.get_inputs():
                _, c, h, w = spec.shape
                y, x = np.mgrid[0:h, 0:w]
                picture = 128 + 80 * np.sin(x / rng.uniform(3, 12) + rng.uniform(0, 6)) * np.cos(y / rng.uniform(3, 12))
                picture = np.clip(picture + rng.normal(0, 20, (h, w)), 0, 255).round().astype(np.uint8)
                values = contract.network_input(picture, standardise, scale).reshape(1, c, h, w)
                feeds[spec.name] = values
                flat.append(values.transpose(0, 2, 3, 1).reshape(-1))
            expected = session.run(None, feeds)[0].reshape(-1)
            inputs, outputs = pathlib.Path(tmp) / "in.f32", pathlib.Path(tmp) / "out.f32"
            np.concatenate(flat).astype(np.float32).tofile(inputs)
            _theirs(h5, isa, 1, inputs, outputs)
            got = np.fromfile(outputs, np.float32)
            worst = max(worst, float(np.max(np.abs(got - expected))))
    return {"cases": cases, "max_abs_difference": worst, "equal": worst < 1e-4}


def compare(args) -> dict:
    host = (ROOT / "models/policy/HOST_MODEL").read_text().strip()
    robot = (ROOT / "models/policy/ROBOT_MODEL").read_text().strip()
    robot_float = robot.removesuffix("-int8")
    networks = [("paper-width fixture CNN", "models/fixtures/cnn", "models/fixtures/cnn-int8"),
                ("host model", f"models/policy/{host}", f"models/policy/{host}-int8"),
                ("robot package's float student", f"models/policy/{robot_float}", f"models/policy/{robot}")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, policy, int8 in networks:
            policy = ROOT / policy
            h5 = pathlib.Path(tmp) / f"{policy.name}.h5"
            export(policy, h5)
            row = {"network": label, "policy": str(policy.relative_to(ROOT)),
                   "engines": []}
            for isa in ISAS:
                print(f"  {label}: {isa}", file=sys.stderr)
                # Alternating runs, the best median of each engine: a busy machine slows
                # some runs; neither engine gets the quieter moments.
                theirs, ours = [], []
                for _ in range(args.repeats):
                    theirs.append(_theirs(h5, isa, args.steps))
                    ours.append(_ours_us(policy, isa, args.steps))
                entry = {"isa": isa, "compiled_nn_us": min(theirs), "dribble_us": min(ours),
                         "compiled_nn_vs_onnxruntime": _commands_agree(policy, h5, isa)}
                if not args.no_callgrind:
                    entry["compiled_nn_instructions"] = _per_pass([str(_driver()), str(h5), "--isa", isa])
                    entry["dribble_instructions"] = _per_pass(
                        [str(_controller()), "forward", "--policy", str(policy / "policy.toml"), "--isa", isa, "--no-peak"])
                row["engines"].append(entry)
            row["onnxruntime"] = {"float_us": _onnxruntime_us(policy, args.repeats, args.steps)}
            if int8 and (ROOT / int8 / "policy.toml").exists():
                row["onnxruntime"]["int8_us"] = _onnxruntime_us(ROOT / int8, args.repeats, args.steps)
                for isa in ("ssse3", "avx2+fma"):
                    best = min(_ours_us(ROOT / int8, isa, args.steps) for _ in range(args.repeats))
                    entry = {"isa": isa, "int8": True, "dribble_us": best}
                    if not args.no_callgrind:
                        entry["dribble_instructions"] = _per_pass(
                            [str(_controller()), "forward", "--policy", str(ROOT / int8 / "policy.toml"),
                             "--isa", isa, "--no-peak"])
                    row["engines"].append(entry)
                row["int8_policy"] = int8
            rows.append(row)
    import onnxruntime as ort

    return {
        "compiled_nn": "compiled-nn-bindings 0.12.0 (B-Human CompiledNN, Keras HDF5 front end)",
        "onnxruntime": f"onnxruntime {ort.__version__} (its kernels for this CPU, one thread; int8 as QDQ)",
        "cpu": _cpu_name(),
        "steps": args.steps,
        "threads": 1,
        "repeats": args.repeats,
        "method": "one process after the other on one machine, the two engines alternating; the best of "
                  "--repeats medians of --steps passes (after a warm-up pass) each; instructions: callgrind, "
                  "(--steps 11) - (--steps 1) over ten",
        "rows": rows,
    }


def _cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.compiled_nn", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    exporting = sub.add_parser("export", help="write a policy's ONNX CNN as a Keras 2 HDF5 file CompiledNN reads")
    exporting.add_argument("policy", type=pathlib.Path)
    exporting.add_argument("out", type=pathlib.Path)
    comparing = sub.add_parser("compare", help="time and count both engines on the shipped networks")
    comparing.add_argument("--steps", type=int, default=2000)
    comparing.add_argument("--repeats", type=int, default=3, help="alternating runs per engine; the best median counts")
    comparing.add_argument("--no-callgrind", action="store_true", help="leave out the instruction counts")
    comparing.add_argument("--out", type=pathlib.Path, default=ROOT / "models/performance/compiled-nn.json")
    args = parser.parse_args(argv)
    if args.command == "export":
        try:
            inputs = export(args.policy, args.out)
        except Unsupported as error:
            print(f"compiled_nn: {args.policy}: {error}", file=sys.stderr)
            return 1
        print(f"wrote {args.out} (inputs {', '.join(inputs)}, channels last)")
        return 0
    result = compare(args)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
