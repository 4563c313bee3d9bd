"""onnxruntime's time per policy step on the committed fixtures: the reference figure beside
`cargo bench --bench policy` (engine and tract), on the same machine, one thread.

    python -m dribble_models.ort_bench [--runs 2000] [--json FILE] [--policy DIR ...]

`--policy DIR` times a shipped one-network policy instead (the CNN rows, float or int8: the
robot package's policy beside the compiled engine's `dribble-controller forward`).

One step is what the controller runs per computed command: the CNN's one network; for the
H-CNN, one of its networks (the gating is a histogram and a nearest centroid, microseconds);
for the R-CNN, one recurrent step with its state fed back. Inputs are random thumbnails
scaled to [0, 1]. Host instruction set only: onnxruntime's kernel library (MLAS) picks its
kernels from the CPU and offers no switch to keep it to SSE.

Reports the median and the 10th/90th percentiles in microseconds, like criterion's middle
figure; nothing is tuned per model.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import sys
import time

import numpy as np
import onnxruntime as ort

from . import manifest as policy_manifest

ROOT = pathlib.Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "models" / "fixtures"
KINDS = {"CNN": ("cnn", "policy.onnx"), "CNN int8": ("cnn-int8", "policy.onnx"), "H-CNN": ("hcnn", "cnn0.onnx"), "R-CNN": ("rcnn", "policy.onnx")}


def session(path: pathlib.Path) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def inputs_for(sess: ort.InferenceSession, rng: np.random.Generator) -> dict[str, np.ndarray]:
    feeds = {}
    for spec in sess.get_inputs():
        shape = [d if isinstance(d, int) else 1 for d in spec.shape]
        if spec.name in ("top", "bottom"):
            feeds[spec.name] = (rng.integers(0, 256, shape) / 255.0).astype(np.float32)
        else:
            feeds[spec.name] = np.zeros(shape, np.float32)
    return feeds


def time_steps(sess: ort.InferenceSession, runs: int, seed: int) -> list[float]:
    feeds = inputs_for(sess, np.random.default_rng(seed))
    names = [o.name for o in sess.get_outputs()]
    recurrent = "h_in" in feeds
    for _ in range(max(50, runs // 20)):  # warm-up
        sess.run(names, feeds)
    times = []
    for _ in range(runs):
        started = time.perf_counter_ns()
        out = sess.run(names, feeds)
        times.append((time.perf_counter_ns() - started) / 1e3)
        if recurrent:
            feeds["h_in"], feeds["c_in"] = out[names.index("h_out")], out[names.index("c_out")]
    return times


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=2000, help="timed steps per kind (default 2000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random thumbnails")
    parser.add_argument("--json", type=pathlib.Path, help="also write the figures here")
    parser.add_argument("--policy", type=pathlib.Path, action="append", default=[], metavar="DIR",
                        help="time this one-network policy directory (its policy.toml's network) instead of the fixtures; repeatable")
    args = parser.parse_args(argv)
    if args.runs < 10:
        parser.error("--runs must be at least 10")
    kinds = {kind: FIXTURES / directory / network for kind, (directory, network) in KINDS.items()}
    if args.policy:
        kinds = {}
        for directory in args.policy:
            manifest = directory / "policy.toml"
            if not manifest.is_file():
                parser.error(f"--policy {directory}: no policy.toml there")
            networks = policy_manifest.load(manifest).get("networks", [])
            if len(networks) != 1:
                parser.error(f"--policy {directory}: {len(networks)} networks; only one-network policies are timed")
            kinds[directory.name] = directory / networks[0]
    report = {"onnxruntime": ort.__version__, "threads": 1, "kinds": {}}
    print(f"onnxruntime {ort.__version__}, 1 thread, {args.runs} steps per kind (µs)")
    for kind, network in kinds.items():
        times = sorted(time_steps(session(network), args.runs, args.seed))
        deciles = statistics.quantiles(times, n=10)
        figures = {"median_us": statistics.median(times), "p10_us": deciles[0], "p90_us": deciles[-1]}
        report["kinds"][kind] = figures
        print(f"  {kind:8} median {figures['median_us']:8.1f}   p10 {figures['p10_us']:8.1f}   p90 {figures['p90_us']:8.1f}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
