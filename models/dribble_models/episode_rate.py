"""Closed-loop episodes an hour with four camera samples a pixel (every shipped result's frames)
and with one (``dribble eval --camera-samples 1``): the same serial ``dribble eval`` of the
same seeds and policy as the throughput table (``dribble_models.cluster_throughput``), after a
short warm-up episode, each setting's runs alternating, with the machine's busy cores over
each run; and what each setting's episodes did, seed by seed. Writes
``models/performance/episode-rate.json`` and the Markdown table the book shows.

    PYTHONPATH=models python -m dribble_models.episode_rate --episodes 30000..30008 --rounds 2

Episodes per core-hour divide the episodes by the wall time and the busy cores (the
simulator, its lavapipe threads and the controller together): on an otherwise idle machine
that is the CPU an episode costs, whatever the core count. Run it on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
from pathlib import Path

from dribble_models.cluster import binary_dir, seed_range
from dribble_models.cluster_throughput import timed

#: The settings compared, in the order each round plays them.
SAMPLES = (4, 1)


def play(samples: int, seeds: str, policy: str, isa: str, scratch: Path, tag: str, env: dict) -> dict:
    """One serial evaluation at `samples` camera samples: its timing and its episodes."""
    trajectories = scratch / f"{tag}.json"
    command = [str(binary_dir() / "dribble"), "eval", "--driver", policy, "--episodes", seeds,
               "--isa", isa, "--camera-samples", str(samples), "--domain", f"rate-{os.getpid()}-{tag}",
               "--trajectories", str(trajectories), "--plot", str(scratch / f"{tag}.png"),
               "--controller-log", str(scratch / f"{tag}.log")]  # fmt: skip
    wall, cores, _ = timed(command, env)
    episodes = json.loads(trajectories.read_text())["episodes"]
    return {
        "wall_s": round(wall, 1),
        "machine_cores_busy": round(cores, 2),
        "outcomes": {str(e["seed"]): e["outcome"] for e in episodes},
        "durations_s": {str(e["seed"]): round(e["duration_s"], 2) for e in episodes},
    }


def summarise(samples: int, runs: list[dict], episodes: int) -> dict:
    """A setting's runs: median wall and busy cores, episodes an hour and a core-hour, goals;
    every run of a setting must have played the same episodes (the renderer is deterministic)."""
    outcomes = [json.dumps(r["outcomes"], sort_keys=True) for r in runs]
    if len(set(outcomes)) != 1:
        raise SystemExit(f"{samples} sample(s): the runs' outcomes differ: {outcomes}")
    wall = statistics.median(r["wall_s"] for r in runs)
    cores = statistics.median(r["machine_cores_busy"] for r in runs)
    goals = sum(o == "goal" for o in runs[0]["outcomes"].values())
    return {
        "camera_samples": samples,
        "runs": runs,
        "wall_s": round(wall, 1),
        "machine_cores_busy": round(cores, 2),
        "episodes_per_hour": round(3600 * episodes / wall),
        "episodes_per_core_hour": round(3600 * episodes / (wall * cores)),
        "goals": goals,
        "episodes": episodes,
        "simulated_s": round(sum(runs[0]["durations_s"].values()), 1),
    }


def table(result: dict) -> str:
    """The Markdown table: a row per setting, with its episodes that end as with four samples
    and its episodes a core-hour against four samples'."""
    rows = result["settings"]
    cost = {r["camera_samples"]: r["wall_s"] * r["machine_cores_busy"] for r in rows}
    lines = ["| camera samples | episodes | goals | ends as with 4 samples | simulated (s) | wall (s, median) | rounds (wall s) | episodes per hour | machine cores busy | episodes per core-hour | against 4 samples |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        samples = r["camera_samples"]
        walls = ", ".join(f"{run['wall_s']:.0f}" for run in r["runs"])
        same = "-" if samples == 4 else f"{result['same_outcomes']} of {r['episodes']}"
        lines.append(f"| {samples} | {r['episodes']} | {r['goals']} | {same} | {r['simulated_s']:.0f} | {r['wall_s']:.0f} | {walls} | "
                     f"{r['episodes_per_hour']} | {r['machine_cores_busy']:.2f} | {r['episodes_per_core_hour']} | {cost[4] / cost[samples]:.2f}x |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=seed_range, default=seed_range("30000..30008"))
    parser.add_argument("--policy", default="models/policy/cnn-dagger1-observable/policy.toml",
                        help="the throughput table's policy (default), or any policy.toml")  # fmt: skip
    parser.add_argument("--isa", default="avx2+fma")
    parser.add_argument("--rounds", type=int, default=2, help="runs of each setting, alternating (default 2)")
    parser.add_argument("--out", type=Path, default=Path("models/performance"))
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")
    seeds = f"{args.episodes.start}..{args.episodes.stop}"
    env = dict(os.environ)
    runs: dict[int, list[dict]] = {samples: [] for samples in SAMPLES}
    with tempfile.TemporaryDirectory() as scratch_dir:
        scratch = Path(scratch_dir)
        # A short episode first, so that no run pays for the first start alone.
        for samples in SAMPLES:
            play(samples, f"{args.episodes.start}..{args.episodes.start + 1}", args.policy, args.isa, scratch, f"warm-{samples}", {**env})
        for round_ in range(args.rounds):
            for samples in SAMPLES:
                run = play(samples, seeds, args.policy, args.isa, scratch, f"{samples}-{round_}", env)
                runs[samples].append(run)
                print(f"round {round_ + 1}, {samples} sample(s): {len(args.episodes)} episodes in {run['wall_s']:.0f} s, "
                      f"{run['machine_cores_busy']:.2f} cores busy", flush=True)  # fmt: skip
    settings = [summarise(samples, runs[samples], len(args.episodes)) for samples in SAMPLES]
    four, one = (s["runs"][0]["outcomes"] for s in settings)
    result = {
        "episodes": seeds,
        "policy": args.policy,
        "isa": args.isa,
        "machine": f"{os.cpu_count()} cores",
        "settings": settings,
        "same_outcomes": sum(four[seed] == one[seed] for seed in four),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "episode-rate.json").write_text(json.dumps(result, indent=1) + "\n")
    text = table(result)
    (args.out / "episode-rate.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
