"""Episodes per hour on this machine: serial ``dribble eval``, then the same seeds as Ray shares
with one and with two workers (``dribble_models.cluster``, a local Ray started for each run),
with the CPU each run kept busy. Writes a JSON and the Markdown table the book shows (docs/src/guide/gym-ray.md)
(``scripts/results`` copies it in); fails unless all runs give the same trajectories file.

    PYTHONPATH=models python -m dribble_models.cluster_throughput \\
        --episodes 30000..30008 --out models/cluster

CPU is counted two ways: the whole machine's busy time from /proc/stat over the run (every
process: the simulator, its lavapipe threads, the controller, Ray's own), in cores on
average; and for the Ray runs the CPU time of the shares' own processes. Run it on an
otherwise idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dribble_models.cluster import binary_dir, seed_range


def busy_and_total() -> tuple[int, int]:
    """The machine's busy and total jiffies since boot (all CPUs)."""
    fields = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = fields[3] + fields[4]  # idle and iowait
    return sum(fields) - idle, sum(fields)


def timed(command: list[str], env: dict) -> tuple[float, float, str]:
    """Runs `command`; its wall seconds, the machine's busy cores on average, its output."""
    busy0, total0 = busy_and_total()
    started = time.perf_counter()
    run = subprocess.run(command, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - started
    busy1, total1 = busy_and_total()
    if run.returncode != 0:
        raise SystemExit(f"{' '.join(command[:4])} ... failed:\n{run.stdout}\n{run.stderr}")
    cores = os.cpu_count() or 1
    return wall, cores * (busy1 - busy0) / max(1, total1 - total0), run.stdout


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=seed_range, default=seed_range("30000..30008"))
    parser.add_argument("--policy", default="models/policy/cnn-dagger1-observable/policy.toml")
    parser.add_argument("--isa", default="avx2+fma")
    parser.add_argument("--out", type=Path, default=Path("models/cluster"))
    args = parser.parse_args(argv)
    seeds = f"{args.episodes.start}..{args.episodes.stop}"
    env = dict(os.environ)
    python = sys.executable
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        # A short episode first, so that no run pays for the first start (page cache, Mesa's
        # shader cache) alone.
        timed([str(binary_dir() / "dribble"), "eval", "--driver", args.policy, "--episodes", f"{args.episodes.start}..{args.episodes.start + 1}", "--time-limit", "2", "--isa", args.isa,
               "--domain", f"warm-up-{os.getpid()}", "--plot", str(Path(scratch) / "warm-up.png"),
               "--controller-log", str(Path(scratch) / "warm-up.log")], env)  # fmt: skip
        files = {}
        runs = [("serial `dribble eval`", "serial", None), ("Ray, 1 worker", "ray1", 1),
                ("Ray, 2 workers", "ray2", 2)]  # fmt: skip
        for label, tag, workers in runs:
            trajectories = Path(scratch) / f"{tag}.json"
            if workers is None:
                command = [str(binary_dir() / "dribble"), "eval", "--driver", args.policy,
                           "--episodes", seeds, "--isa", args.isa, "--domain", f"throughput-{os.getpid()}",
                           "--trajectories", str(trajectories), "--plot", str(Path(scratch) / f"{tag}.png"),
                           "--controller-log", str(Path(scratch) / f"{tag}.log")]  # fmt: skip
            else:
                command = [python, "-m", "dribble_models.cluster", "eval", "--episodes", seeds,
                           "--workers", str(workers), "--share", "2",
                           "--trajectories", str(trajectories), "--plot", str(Path(scratch) / f"{tag}.png"),
                           "--", "--driver", args.policy, "--isa", args.isa]  # fmt: skip
            wall, cores, output = timed(command, env)
            share_cpu = None
            for line in output.splitlines():
                if "CPU s in the shares" in line:
                    share_cpu = float(line.split(" CPU s in the shares")[0].rsplit(", ", 1)[1])
            files[tag] = trajectories.read_bytes()
            episodes = len(args.episodes)
            rows.append({"run": label, "episodes": episodes, "wall_s": round(wall, 1),
                         "episodes_per_hour": round(3600 * episodes / wall),
                         "machine_cores_busy": round(cores, 2),
                         "share_cpu_s": share_cpu})  # fmt: skip
            print(f"{label}: {episodes} episodes in {wall:.0f} s, {3600 * episodes / wall:.0f} per hour, "
                  f"{cores:.2f} cores busy", flush=True)  # fmt: skip
        same = len(set(files.values())) == 1
    result = {
        "episodes": seeds,
        "policy": args.policy,
        "machine": f"{os.cpu_count()} cores",
        "identical_trajectories": same,
        "runs": rows,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "throughput.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = ["| run | episodes | wall (s) | episodes per hour | machine cores busy | shares' CPU (s) |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        share = "" if r["share_cpu_s"] is None else f"{r['share_cpu_s']:.0f}"
        lines.append(f"| {r['run']} | {r['episodes']} | {r['wall_s']:.0f} | {r['episodes_per_hour']} | "
                     f"{r['machine_cores_busy']:.2f} | {share} |")  # fmt: skip
    (args.out / "throughput.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print("trajectories identical in all runs" if same else "TRAJECTORIES DIFFER")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
