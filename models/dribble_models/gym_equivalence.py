"""Does the Gymnasium environment play as ``dribble eval`` does? A shipped one-network policy
drives ``dribble/NaoDribble-v0`` from Python through onnxruntime, and the same policy plays
the same seeds in ``dribble eval`` (the controller's compiled engine); the table compares
outcomes, computed commands and the 10 Hz paths, and gives the environment's steps per
second.

    PYTHONPATH=models python -m dribble_models.gym_equivalence \\
        --policy models/policy/cnn-dagger1-observable/policy.toml --episodes 10000..10005

The two engines round differently (onnxruntime against the compiled engine, about 1e-6 on a
command); a camera image turns such differences into slightly different images, so the paths
drift apart by about a millimetre over ten seconds, as they do between the controller's own
two engines (compiled and tract). With the teacher's commands from ``info`` instead of a
network (``--teacher``), nothing is rounded differently and the paths are equal bit for bit.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dribble_models import contract
from dribble_models.cluster import seed_range
from dribble_models.gym_env import NaoDribbleEnv, find_dribble


class OnnxPolicy:
    """A shipped one-network float policy (kind cnn) run by onnxruntime on one thread."""

    def __init__(self, manifest_path: Path):
        import onnxruntime

        manifest = tomllib.loads(manifest_path.read_text())
        if manifest.get("kind") != "cnn" or len(manifest.get("networks", [])) != 1:
            raise ValueError(
                f"{manifest_path}: only one-network CNN policies run here "
                f"(kind {manifest.get('kind')!r}); the H-CNN gates and the R-CNN carries state"
            )
        if manifest.get("precision", "float32") != "float32":
            raise ValueError(f"{manifest_path}: a float policy, not {manifest['precision']}")
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        network = manifest_path.parent / manifest["networks"][0]
        self.session = onnxruntime.InferenceSession(str(network), options)
        self.scale = float(manifest["normalisation"]["scale"])
        self.standardise = bool(manifest["normalisation"].get("standardise", False))
        self.top = manifest["inputs"]["top"]["name"]
        self.bottom = manifest["inputs"]["bottom"]["name"]
        # A network that reads the last command sent (`[inputs] previous`) is fed the command
        # this object answered last, clamped as the controller sends it; zero after `reset`.
        previous = manifest["inputs"].get("previous")
        self.previous_input = previous["name"] if previous else None
        self.previous = np.zeros(3, dtype=np.float32)

    @property
    def reads_previous(self) -> bool:
        return self.previous_input is not None

    def reset(self) -> None:
        """An episode's start: the last command is a stop."""
        self.previous = np.zeros(3, dtype=np.float32)

    def __call__(self, observation, info=None) -> np.ndarray:
        feed = {
            self.top: contract.network_input(observation["top"][None, None], self.standardise, self.scale),
            self.bottom: contract.network_input(observation["bottom"][None, None], self.standardise, self.scale),
        }
        if self.previous_input is not None:
            feed[self.previous_input] = self.previous[None]
        command = self.session.run(None, feed)[0][0]
        # The controller's rule: a non-finite command is a stop, each component clamped.
        finite = np.all(np.isfinite(command))
        self.previous = np.clip(command, -1.0, 1.0).astype(np.float32) if finite else np.zeros(3, np.float32)
        return command


@dataclass
class Played:
    seed: int
    outcome: str
    computed_commands: int
    robot: np.ndarray
    ball: np.ndarray
    steps: int = 0
    wall_s: float = 0.0


def play_in_environment(policy, seeds, time_limit_s: float, expert: str = "paper") -> list[Played]:
    """Each seed played in the environment; `policy` maps (observation, info) to an action."""
    played = []
    env = NaoDribbleEnv(expert=expert, time_limit_s=time_limit_s)
    try:
        for seed in seeds:
            observation, info = env.reset(seed=seed)
            if hasattr(policy, "reset"):
                policy.reset()
            started, steps = time.perf_counter(), 0
            while True:
                observation, _, terminated, truncated, info = env.step(policy(observation, info))
                steps += 1
                if terminated or truncated:
                    break
            trajectory = info["trajectory"]
            played.append(
                Played(
                    seed=seed,
                    outcome=info["outcome"],
                    computed_commands=info["computed_commands"],
                    robot=np.asarray(trajectory["robot"]),
                    ball=np.asarray(trajectory["ball"]),
                    steps=steps,
                    wall_s=time.perf_counter() - started,
                )
            )
    finally:
        env.close()
    return played


def play_in_eval(driver: str, seeds, time_limit_s: float, expert: str = "paper") -> list[Played]:
    """The same seeds in `dribble eval` (in process; the expert renders its cameras too)."""
    with tempfile.TemporaryDirectory() as scratch:
        trajectories = Path(scratch) / "trajectories.json"
        command = [
            find_dribble(), "eval", "--driver", driver,
            "--episodes", f"{seeds[0]}..{seeds[-1] + 1}",
            "--time-limit", repr(time_limit_s), "--transport", "in-process",
            "--plot", str(Path(scratch) / "plot.png"), "--trajectories", str(trajectories),
            "--controller-log", str(Path(scratch) / "controller.log"),
        ]  # fmt: skip
        if driver in ("teacher", "expert"):
            command += ["--teacher", expert, "--render"]
        run = subprocess.run(command, capture_output=True, text=True)
        if run.returncode != 0:
            raise RuntimeError(f"dribble eval failed:\n{run.stdout}\n{run.stderr}")
        episodes = json.loads(trajectories.read_text())["episodes"]
    return [
        Played(
            seed=e["seed"],
            outcome=e["outcome"],
            computed_commands=e["computed_commands"],
            robot=np.asarray(e["robot"]),
            ball=np.asarray(e["ball"]),
        )
        for e in episodes
        if e["seed"] in seeds
    ]


def largest_gap(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance between two 10 Hz paths at the same instant, over the instants
    both have (an episode that ends earlier has fewer)."""
    n = min(len(a), len(b))
    return float(np.max(np.linalg.norm(a[:n] - b[:n], axis=1))) if n else 0.0


def parting_time(a: np.ndarray, b: np.ndarray, apart_m: float = 0.01) -> float | None:
    """When two 10 Hz paths are first more than `apart_m` apart, seconds (None: never)."""
    n = min(len(a), len(b))
    apart = np.flatnonzero(np.linalg.norm(a[:n] - b[:n], axis=1) > apart_m)
    return float(apart[0]) / 10 if len(apart) else None


def compare(environment: list[Played], evaluation: list[Played]) -> list[dict]:
    rows = []
    for env_run, eval_run in zip(environment, evaluation, strict=True):
        assert env_run.seed == eval_run.seed
        rows.append(
            {
                "seed": env_run.seed,
                "outcome_env": env_run.outcome,
                "outcome_eval": eval_run.outcome,
                "commands_env": env_run.computed_commands,
                "commands_eval": eval_run.computed_commands,
                "robot_gap_m": largest_gap(env_run.robot, eval_run.robot),
                "ball_gap_m": largest_gap(env_run.ball, eval_run.ball),
                "apart_after_s": parting_time(env_run.robot, eval_run.robot),
                "steps_per_s": env_run.steps / env_run.wall_s if env_run.wall_s else 0.0,
            }
        )
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", default="models/policy/cnn-dagger1-observable/policy.toml")
    parser.add_argument("--teacher", action="store_true",
                        help="drive with the teacher's command from info instead of the policy")
    parser.add_argument("--expert", default="paper", choices=["paper", "observable", "orbit"])
    parser.add_argument("--episodes", type=seed_range, default=seed_range("10000..10003"),
                        help="seed range START..END (END excluded)")
    parser.add_argument("--time-limit", type=float, default=90.0)
    parser.add_argument("--json", type=Path, help="also write the rows here")
    parser.add_argument("--markdown", type=Path, help="also write the table (Markdown) here")
    args = parser.parse_args(argv)  # fmt: skip
    args.episodes = list(args.episodes)

    if args.teacher:
        environment = play_in_environment(
            lambda _, info: info["expert_command"].astype(np.float32),
            args.episodes, args.time_limit, args.expert,
        )  # fmt: skip
        evaluation = play_in_eval("teacher", args.episodes, args.time_limit, args.expert)
    else:
        policy = OnnxPolicy(Path(args.policy))
        environment = play_in_environment(policy, args.episodes, args.time_limit)
        evaluation = play_in_eval(args.policy, args.episodes, args.time_limit)
    rows = compare(environment, evaluation)
    def apart(r):
        return "never" if r["apart_after_s"] is None else f"{r['apart_after_s']:.1f} s"

    print(f"{'seed':>6}  {'env':<10}  {'eval':<10}  {'commands':>13}  {'robot gap (m)':>13}  "
          f"{'ball gap (m)':>12}  {'1 cm apart':>10}  {'steps/s':>7}")  # fmt: skip
    for r in rows:
        print(f"{r['seed']:>6}  {r['outcome_env']:<10}  {r['outcome_eval']:<10}  "
              f"{r['commands_env']:>6}/{r['commands_eval']:<6}  {r['robot_gap_m']:>13.2e}  "
              f"{r['ball_gap_m']:>12.2e}  {apart(r):>10}  {r['steps_per_s']:>7.1f}")  # fmt: skip
    same = sum(r["outcome_env"] == r["outcome_eval"] for r in rows)
    steps = sum(p.steps for p in environment)
    wall = sum(p.wall_s for p in environment)
    print(f"same outcome in {same} of {len(rows)}; environment {steps / wall:.1f} steps per second "
          f"({steps} steps, {wall:.0f} s, policy included)")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    if args.markdown:
        lines = ["| seed | outcome, environment | outcome, `dribble eval` | commands | largest robot gap (m) "
                 "| largest ball gap (m) | robot paths 1 cm apart after | steps per second |",
                 "|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for r in rows:
            lines.append(f"| {r['seed']} | {r['outcome_env']} | {r['outcome_eval']} | "
                         f"{r['commands_env']} / {r['commands_eval']} | {r['robot_gap_m']:.1e} | "
                         f"{r['ball_gap_m']:.1e} | {apart(r)} | {r['steps_per_s']:.1f} |")  # fmt: skip
        args.markdown.write_text("\n".join(lines) + "\n")
    return 0 if same == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
