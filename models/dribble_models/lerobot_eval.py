"""dribble's episodes in LeRobot's evaluation: an environment configuration LeRobot's
`make_env` builds, and the shipped ONNX policy as a LeRobot policy, played by LeRobot's own
`eval_policy` (the function behind `lerobot-eval`).

    scripts/lerobot eval --policy models/policy/NAME --seeds 20000..20020 --out FILE.json

- **Environment.** `DribbleEnv` is registered with LeRobot as `--env.type=dribble`
  (`EnvConfig.register_subclass`); its gym id is `gym_dribble/NaoDribble-v0`, which the
  `gym_dribble` package registers on import as LeRobot's convention asks. It wraps the
  project's Gymnasium environment (`dribble_models.gym_env`: the same simulator, renderer and
  controller code as `dribble eval`) and hands LeRobot the observation it expects:
  `{"pixels": {"top": uint8 (120, 160, 3), "bottom": uint8 (60, 80, 3)}}`, the thumbnails'
  luma in three equal channels, as the exported datasets store them
  (`dribble_models.lerobot_format`), so `observation.images.top` and `.bottom` reach a policy
  as they reach one trained on those datasets, and `agent_pos` (LeRobot's
  `observation.state`) as the exports' two zeros: the robot has no state beyond its images.
  The action is the normalised speed command
  `[forward, left, turn]`. Success is dribble's own outcome: `info["is_success"]` is true
  exactly when the episode ends in a goal; the 90 s limit is the environment's own.
- **Policy.** `DribbleOnnxPolicy` is a LeRobot `PreTrainedPolicy` that runs a shipped
  float policy's ONNX network under onnxruntime: it turns LeRobot's float images back into
  the u8 thumbnails (exactly: they were u8 / 255), makes the network's input as the
  controller does (`contract.network_input`, `[normalisation]` of the manifest), and returns
  the command. dribble's controller then clamps it, as in `dribble eval`. A policy LeRobot
  trained (a `pretrained_model` directory: `config.json`, `model.safetensors` and its
  processors, as `lerobot-train` saves one, e.g. `scripts/lerobot train-act`) is loaded with
  LeRobot's own classes and plays through its own saved pre- and post-processors
  (normalisation of images, state and action), on the CPU.

LeRobot seeds each episode (`start_seed`); it is called once a seed, so each finished
episode is written to a journal (`OUT.partial/SEED.json`) before the next starts, and a run
cut off continues from there when the same command runs again (a journal of another policy,
condition, limit or chunking is refused). `--jobs N` plays N episodes at once, each job a
process of its own with one torch thread. The summary written has one row per seed with
LeRobot's success and dribble's outcome, the goals with their Wilson interval, and the time
taken. Runs only in LeRobot's environment (`scripts/lerobot`).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from torch import Tensor

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.policies.pretrained import PreTrainedPolicy

from . import contract
from .cluster import seed_range
from .gym_env import NaoDribbleEnv
from .gym_equivalence import OnnxPolicy
from .teachers import wilson

GYM_ID = "gym_dribble/NaoDribble-v0"
#: LeRobot's rollout stops after this many steps; dribble's own 90 s limit (2,700 commands at
#: the camera's 30 Hz) ends every episode before it.
MAX_STEPS = 3000
TOP = "observation.images.top"
BOTTOM = "observation.images.bottom"
STATE = "observation.state"
#: The exports' `observation.state`: two zeros (dribble_models.lerobot_format says why).
STATE_SIZE = 2


class LeRobotObservations(gym.ObservationWrapper):
    """dribble's `{"top", "bottom"}` luma thumbnails as LeRobot's `{"pixels": {...}}` of
    three-channel images, and dribble's outcome as LeRobot's `is_success`."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Dict(
            {
                "pixels": gym.spaces.Dict(
                    {
                        "top": gym.spaces.Box(0, 255, (*contract.TOP_SHAPE, 3), np.uint8),
                        "bottom": gym.spaces.Box(0, 255, (*contract.BOTTOM_SHAPE, 3), np.uint8),
                    }
                ),
                "agent_pos": gym.spaces.Box(0.0, 0.0, (STATE_SIZE,), np.float32),
            }
        )

    def observation(self, observation: dict) -> dict:
        return {
            "pixels": {name: np.repeat(np.asarray(observation[name])[:, :, None], 3, axis=2) for name in ("top", "bottom")},
            "agent_pos": np.zeros(STATE_SIZE, np.float32),
        }

    def step(self, action):
        observation, reward, terminated, truncated, info = super().step(action)
        if terminated or truncated:
            info["is_success"] = info.get("outcome") == "goal"
        return observation, reward, terminated, truncated, info


def make_lerobot_env(**kwargs) -> gym.Env:
    """The environment LeRobot's `make_env` builds (gym id `gym_dribble/NaoDribble-v0`)."""
    return LeRobotObservations(NaoDribbleEnv(**kwargs))


def register() -> None:
    """Registers the gym id where LeRobot looks for it (idempotent)."""
    if GYM_ID not in gym.registry:
        gym.register(id=GYM_ID, entry_point=make_lerobot_env, max_episode_steps=MAX_STEPS)


@EnvConfig.register_subclass("dribble")
@dataclass
class DribbleEnv(EnvConfig):
    """`--env.type=dribble`: the Nao dribbling from its two cameras (`conditions` as
    `dribble eval --condition` takes them; `teacher` only fills `info`)."""

    task: str | None = "NaoDribble-v0"
    fps: int = 30
    episode_length: int = MAX_STEPS
    conditions: str = "clean"
    teacher: str = "paper"
    #: The episode's limit, simulated seconds (the paper's 90; shorter only for smoke tests).
    time_limit_s: float = 90.0
    features: dict[str, PolicyFeature] = field(
        default_factory=lambda: {
            "action": PolicyFeature(type=FeatureType.ACTION, shape=(3,)),
            "pixels/top": PolicyFeature(type=FeatureType.VISUAL, shape=(*contract.TOP_SHAPE, 3)),
            "pixels/bottom": PolicyFeature(type=FeatureType.VISUAL, shape=(*contract.BOTTOM_SHAPE, 3)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(STATE_SIZE,)),
        }
    )
    features_map: dict[str, str] = field(
        default_factory=lambda: {"action": "action", "pixels/top": TOP, "pixels/bottom": BOTTOM, "agent_pos": STATE}
    )

    @property
    def gym_kwargs(self) -> dict:
        return {
            "condition": self.conditions,
            "expert": self.teacher,
            "time_limit_s": self.time_limit_s,
            "max_episode_steps": self.episode_length,
        }


@PreTrainedConfig.register_subclass("dribble_onnx")
@dataclass
class DribbleOnnxConfig(PreTrainedConfig):
    """A shipped dribble float policy (`policy.toml` and its ONNX network)."""

    model: str = ""
    device: str | None = "cpu"
    push_to_hub: bool = False
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=dict)

    def __post_init__(self) -> None:
        super().__post_init__()
        self.input_features = {
            TOP: PolicyFeature(type=FeatureType.VISUAL, shape=(3, *contract.TOP_SHAPE)),
            BOTTOM: PolicyFeature(type=FeatureType.VISUAL, shape=(3, *contract.BOTTOM_SHAPE)),
        }
        self.output_features = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(3,))}

    @property
    def observation_delta_indices(self) -> None:
        return None

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self):
        raise NotImplementedError("a shipped dribble policy is evaluated here, not trained")

    def get_scheduler_preset(self) -> None:
        return None

    def validate_features(self) -> None:
        return None


class DribbleOnnxPolicy(PreTrainedPolicy):
    """The shipped ONNX network as a LeRobot policy (module doc)."""

    config_class = DribbleOnnxConfig
    name = "dribble_onnx"

    def __init__(self, config: DribbleOnnxConfig) -> None:
        super().__init__(config)
        manifest_path = Path(config.model)
        # The Gymnasium comparison's onnxruntime runner: the same checks and network input.
        self.network = OnnxPolicy(manifest_path / "policy.toml" if manifest_path.is_dir() else manifest_path)

    def get_optim_params(self) -> dict:
        return {}

    def reset(self) -> None:
        """An episode's start: a CNN carries nothing from one step to the next but, where it
        reads one, the last command sent."""
        self.network.reset()

    def forward(self, batch: dict[str, Tensor]):
        raise NotImplementedError("a shipped dribble policy is evaluated here, not trained")

    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        return self.select_action(batch)[:, None]

    @staticmethod
    def thumbnails(images: Tensor) -> np.ndarray:
        """LeRobot's float images [B, 3, H, W] in [0, 1] back to the u8 luma [B, H, W]."""
        return np.rint(images[:, 0].detach().cpu().numpy().astype(np.float64) * 255.0).astype(np.uint8)

    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        tops, bottoms = self.thumbnails(batch[TOP]), self.thumbnails(batch[BOTTOM])
        if self.network.reads_previous and len(tops) != 1:
            raise ValueError(
                f"{self.config.model}: a policy that reads its last command runs one environment "
                f"at a time (a batch of {len(tops)} shares one last command)"
            )
        commands = [self.network({"top": top, "bottom": bottom}) for top, bottom in zip(tops, bottoms)]
        return torch.from_numpy(np.asarray(commands, dtype=np.float32))


class OutcomeLog(gym.Wrapper):
    """Keeps each finished episode's seed and dribble outcome, beside LeRobot's own record."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.finished: list[dict] = []

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        if terminated or truncated:
            self.finished.append(
                {"seed": int(info["seed"]), "outcome": info.get("outcome"), "duration_s": float(info.get("duration_s", 0.0)), "is_success": bool(info.get("is_success"))}
            )
        return observation, reward, terminated, truncated, info


def is_lerobot_checkpoint(model: Path) -> bool:
    """Whether `model` is a policy LeRobot saved (`config.json` and `model.safetensors`)."""
    return (model / "config.json").is_file() and (model / "model.safetensors").is_file()


def policy_and_processors(model: Path, action_steps: int | None = None):
    """The policy at `model` with the processors it plays through: a shipped dribble model's
    ONNX network with none (its normalisation is the manifest's, inside the policy), or a
    LeRobot checkpoint with the pre- and post-processors saved beside it. `action_steps`
    sets a chunking policy's `n_action_steps`: how many commands of each predicted chunk it
    sends before it runs again (ACT as its authors run it sends the whole chunk)."""
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action

    if not is_lerobot_checkpoint(model):
        if action_steps is not None:
            raise ValueError(f"--action-steps is for a LeRobot policy that predicts chunks; {model} sends one command a step")
        identity = PolicyProcessorPipeline(steps=[])
        actions = PolicyProcessorPipeline(steps=[], to_transition=policy_action_to_transition, to_output=transition_to_policy_action)
        return DribbleOnnxPolicy(DribbleOnnxConfig(model=str(model))), identity, actions, "onnxruntime"
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    config = PreTrainedConfig.from_pretrained(model)
    config.device = "cpu"
    if action_steps is not None:
        chunk = getattr(config, "chunk_size", None)
        if chunk is None or not 1 <= action_steps <= chunk:
            raise ValueError(f"--action-steps {action_steps}: {model} predicts chunks of {chunk} commands")
        config.n_action_steps = action_steps
    policy = get_policy_class(config.type).from_pretrained(model, config=config)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(
        config, pretrained_path=str(model), preprocessor_overrides={"device_processor": {"device": "cpu"}}
    )
    return policy, preprocessor, postprocessor, f"LeRobot {config.type}"


def run_key(model: Path, conditions: str, time_limit_s: float, action_steps: int | None) -> dict:
    """What makes two episodes parts of one run: a journal holding another run's is refused."""
    return {"policy": str(model.resolve()), "conditions": conditions, "time_limit_s": time_limit_s, "action_steps": action_steps}


def journaled(journal: Path, key: dict) -> dict[int, dict]:
    """The episodes a cut-off run left in `journal` (one `SEED.json` each), by seed."""
    episodes = {}
    for path in sorted(journal.glob("*.json")) if journal.is_dir() else []:
        row = json.loads(path.read_text())
        if row.get("run") != key:
            raise ValueError(f"{path} is an episode of another run ({row.get('run')}); remove {journal} to start again")
        episodes[int(row["seed"])] = {name: value for name, value in row.items() if name != "run"}
    return episodes


def play(model: Path, seeds: list[int], conditions: str, time_limit_s: float, action_steps: int | None, journal: Path, threads: int | None = None) -> None:
    """LeRobot's `make_env` and `eval_policy` on each of `seeds`, one episode at a time, each
    finished episode written to `journal` (`SEED.json`) before the next starts."""
    from lerobot.envs.factory import make_env
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.scripts.lerobot_eval import eval_policy

    if threads is not None:
        torch.set_num_threads(threads)
    register()
    key = run_key(model, conditions, time_limit_s, action_steps)
    policy, preprocessor, postprocessor, _ = policy_and_processors(model, action_steps)
    config = DribbleEnv(conditions=conditions, time_limit_s=time_limit_s)
    environments = make_env(config, n_envs=1)
    vector_env = environments["dribble"][0]
    outcomes = vector_env.envs[0] = OutcomeLog(vector_env.envs[0])
    identity = PolicyProcessorPipeline(steps=[])
    journal.mkdir(parents=True, exist_ok=True)
    try:
        for seed in seeds:
            started = time.monotonic()
            with torch.no_grad():
                info = eval_policy(vector_env, policy, identity, identity, preprocessor, postprocessor, n_episodes=1, start_seed=seed)
            (row,) = outcomes.finished[-1:]
            if row["seed"] != seed:
                raise RuntimeError(f"LeRobot played seed {row['seed']} where {seed} was asked for")
            (lerobot,) = info["per_episode"]
            row = {**row, "lerobot_success": bool(lerobot["success"]), "wall_s": round(time.monotonic() - started, 1)}
            written = journal / f"{seed}.json.tmp"
            written.write_text(json.dumps({**row, "run": key}) + "\n")
            written.replace(journal / f"{seed}.json")
            print(f"seed {seed}: {row['outcome']} after {row['duration_s']:.1f} s simulated, {row['wall_s']:.0f} s wall", file=sys.stderr, flush=True)
    finally:
        vector_env.close()


def evaluate(model: Path, seeds: range, conditions: str, journal: Path, time_limit_s: float = 90.0, action_steps: int | None = None, jobs: int = 1) -> dict:
    """`seeds` played through LeRobot's `eval_policy` (`play`), `jobs` processes at once,
    each episode kept in `journal` as it ends, so a run cut off continues where it stopped;
    the summary of all of them, in seed order."""
    import multiprocessing

    key = run_key(model, conditions, time_limit_s, action_steps)
    *_, runner = policy_and_processors(model, action_steps)  # refuses a bad policy or chunk before any episode
    earlier = journaled(journal, key)
    missing = [seed for seed in seeds if seed not in earlier]
    if earlier:
        print(f"scripts/lerobot eval: {len(earlier)} episodes kept in {journal}, {len(missing)} to play", file=sys.stderr)
    started = time.monotonic()
    jobs = max(1, min(jobs, len(missing)))
    shares = [missing[job::jobs] for job in range(jobs)]
    if jobs == 1:
        if missing:
            play(model, missing, conditions, time_limit_s, action_steps, journal)
    else:
        # Spawned, not forked: each job loads its own torch, policy, renderer and simulator.
        context = multiprocessing.get_context("spawn")
        workers = [context.Process(target=play, args=(model, share, conditions, time_limit_s, action_steps, journal, 1)) for share in shares]
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join()
        failed = [worker.exitcode for worker in workers if worker.exitcode != 0]
        if failed:
            raise RuntimeError(f"{len(failed)} of {jobs} evaluation jobs failed (exit codes {failed}); the episodes they finished are kept in {journal}")
    played = journaled(journal, key)
    episodes = [played[seed] for seed in seeds if seed in played]
    if len(episodes) != len(seeds):
        raise RuntimeError(f"{len(seeds) - len(episodes)} episodes missing from {journal}")
    goals = sum(e["outcome"] == "goal" for e in episodes)
    low, high = wilson(goals, len(episodes))
    return {
        "path": f"lerobot eval_policy (LeRobot 0.4.4) over gym_dribble/NaoDribble-v0, {runner}",
        "policy": str(model),
        "conditions": conditions,
        "time_limit_s": time_limit_s,
        **({"action_steps": action_steps} if action_steps is not None else {}),
        "seeds": f"{seeds.start}..{seeds.stop - 1}",
        "goals": goals,
        "episodes": len(episodes),
        "interval": [round(low, 3), round(high, 3)],
        "lerobot_pc_success": round(100.0 * sum(e["lerobot_success"] for e in episodes) / max(1, len(episodes)), 1),
        "jobs": jobs,
        "wall_s": round(time.monotonic() - started, 1),
        "episode_wall_s": round(sum(e["wall_s"] for e in episodes), 1),
        "per_episode": episodes,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/lerobot eval", description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", type=Path, required=True, help="a shipped float CNN (models/policy/NAME or its policy.toml), or a policy LeRobot trained (a checkpoint's pretrained_model directory)")
    parser.add_argument("--seeds", type=seed_range, required=True, metavar="A..B", help="the episodes' seeds, A to B - 1")
    parser.add_argument("--condition", default="clean", help="as `dribble eval --condition` takes it")
    parser.add_argument("--time-limit", type=float, default=90.0, help="simulated seconds per episode (the paper's 90)")
    parser.add_argument("--out", type=Path, required=True, help="the summary (JSON)")
    parser.add_argument("--action-steps", type=int, help="a LeRobot policy that predicts chunks (ACT): how many commands of each chunk it sends before it runs again, its n_action_steps (default the checkpoint's: 1 for scripts/lerobot train-act's, a reactive policy; the chunk's length runs it once a chunk, a tenth of the time for chunks of 10)")
    parser.add_argument("--jobs", type=int, default=1, help="episodes played at once, each in a process of its own with one torch thread (default 1)")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error("--jobs must be at least 1")
    journal = args.out.with_name(args.out.name + ".partial")
    try:
        summary = evaluate(args.policy, args.seeds, args.condition, journal, args.time_limit, args.action_steps, args.jobs)
    except ValueError as error:
        print(f"scripts/lerobot eval: {error}", file=sys.stderr)
        return 2
    except RuntimeError as error:
        print(f"scripts/lerobot eval: {error}", file=sys.stderr)
        return 1
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=1) + "\n")
    shutil.rmtree(journal, ignore_errors=True)
    low, high = summary["interval"]
    print(f"goals {summary['goals']} / {summary['episodes']} ({low:.2f}-{high:.2f}) through LeRobot's eval_policy, {summary['wall_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
