"""A study: does the robot's own last command, as a second input, take the host model out of
its standstill beside the ball?

Beside the ball, facing a wall of a venue it cannot read, a reactive CNN cannot tell on which
side of the ball-to-goal line it stands; the teacher's two detours around the ball average to
a stop in its regression, and the robot stands there until the time runs out
(docs/src/history/two-hypotheses-at-the-ball.md). The command the robot executed last is
known on the robot (the controller sent it); fed back, it breaks the tie the way the robot
was already moving. The risk is the known one of imitation with the past action as input
(the copycat: a network that learns to repeat its last command rather than read its
images), whose remedy is DAgger's rounds.

Before the policy contract changes on both sides (a third network input in the controller
and the engine), this module asks the question in Python, with the controller's own
thumbnails through the Gymnasium environment:

    python -m dribble_models.previous_command train --start models/policy/HOST --dataset DIR --out RUN.pt
    python -m dribble_models.previous_command play RUN.pt --seeds 20000..20020 --condition unseen-venue:3 --out S.json
    python -m dribble_models.previous_command round RUN.pt --seeds 4000..4030 --condition randomized --out ROUND/
    python -m dribble_models.previous_command train ... --round ROUND/
    python -m dribble_models.previous_command report models/studies/previous-command

- **The network** (`PreviousCommandCNN`): the start's camera branches, kept fixed, and its
  dense layers with three more inputs into the hidden layer, the last command sent
  (normalised, clamped as the controller clamps it; zero at an episode's start), their
  weights zero at the start, so the run begins as the start's function. `--only-previous`
  trains those weights alone, so the start's function stays wherever the last command is
  zero and the rest of the head is the start's.
- **Training rows**: a teacher-driven recording executes the teacher's commands, so the
  command before row t is row t-1's label (`previous_commands`). The camera features are
  computed once (they are fixed), so an epoch over the head takes seconds. The last command
  is perturbed on training rows (`--previous-noise`, Gaussian, in normalised units) so the
  network cannot read its label off it to the last digit.
- **DAgger** (`round`): the network drives (the teacher's command executed instead with
  probability `--beta`, per computed command, seeded by the episode), the teacher labels
  every state it visits, and each row keeps the command executed before it; `train
  --round DIR` adds those rows, so the network learns what to send after its own commands.
- **Play** (`play`): the Gymnasium environment (the same simulator, renderer and controller
  code as `dribble eval`), the network in PyTorch on one thread, the command it sent fed
  back; the summary is `dribble_models.eval_summary`'s, failure classes included.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from .cluster import seed_range
from .command_metric import row_errors, sent_commands
from .dataset import PHASES, DatasetError, Episode, executed_before, load
from .eval_summary import summarise_episode
from .networks import CNN, CameraFeatures, PreviousCommandCNN, set_standardise, to_network_input
from .seed_ranges import refuse_reserved
from .shipped_weights import load_shipped_weights

def previous_commands(commands: np.ndarray) -> np.ndarray:
    """The command sent before each row of a teacher-driven episode: the row before's,
    clamped as the controller clamps it; zero before the first (`dataset.executed_before`)."""
    return executed_before(commands)


def start_model(path: Path) -> CNN:
    """A shipped one-network float CNN (`models/policy/NAME`) as a torch module."""
    cnn = CNN()
    load_shipped_weights(cnn, path, "cnn")
    cnn.eval()
    return cnn


@torch.no_grad()
def camera_features(features: CameraFeatures, episodes: list[Episode], chunk: int = 512) -> np.ndarray:
    """The fixed branches' features of every row of `episodes`, in order [N, F]."""
    features.eval()
    out = []
    for episode in tqdm(episodes, desc="camera features", unit="episode", leave=False):
        for i in range(0, len(episode), chunk):
            top, bottom = to_network_input(episode.top[i : i + chunk], episode.bottom[i : i + chunk])
            out.append(features(top, bottom).numpy())
    return np.concatenate(out)


def split_validation(seeds: list[int], count: int, seed: int) -> tuple[list[int], list[int]]:
    """(training seeds, validation seeds): `count` whole episodes held out, a seeded choice."""
    order = np.random.default_rng(seed).permutation(len(seeds))
    held = sorted(seeds[i] for i in order[:count])
    return [s for s in seeds if s not in held], held


def round_episodes(directory: Path) -> list[tuple[Episode, np.ndarray]]:
    """The (episode, command executed before each row) pairs a `round` left in `directory`."""
    pairs = []
    files = sorted(Path(directory).glob("episode_*.npz"))
    if not files:
        raise DatasetError(f"{directory} holds no round episodes (episode_*.npz): record one with `round`")
    for file in files:
        with np.load(file) as arrays:
            episode = Episode(int(arrays["seed"]), arrays["top"], arrays["bottom"], arrays["command"].astype(np.float32), arrays["phase"])
            pairs.append((episode, arrays["previous"].astype(np.float32)))
    refuse_reserved([e.seed for e, _ in pairs], f"the round {directory}")
    return pairs


def train(args: argparse.Namespace) -> int:
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    episodes = []
    names = []
    for directory in args.dataset:
        dataset = load(directory)
        refuse_reserved(dataset.seeds(), f"the dataset {directory}")
        episodes += dataset.episodes
        names.append(f"{directory} ({dataset.content_hash[:12]})")
    seeds = [e.seed for e in episodes]
    if len(set(seeds)) != len(seeds):
        raise DatasetError("the datasets share episode seeds")
    training_seeds, validation_seeds = split_validation(seeds, args.validation_episodes, args.seed)
    # (episode, the command executed before each of its rows): the teacher's own in a
    # demonstration, the recorded one in a round.
    held = set(validation_seeds)
    training = [(e, previous_commands(e.command)) for e in episodes if e.seed not in held]
    validation = [(e, previous_commands(e.command)) for e in episodes if e.seed in held]
    for directory in args.round:
        added = round_episodes(directory)
        training += added
        names.append(f"{directory} (round, {len(added)} episodes)")
    start = start_model(args.start)
    model = PreviousCommandCNN.from_cnn(start)
    for parameter in model.features.parameters():
        parameter.requires_grad_(False)
    if args.only_previous:
        # The start's function kept wherever the last command is zero: only the last
        # command's weights into the hidden layer learn (the rest of the head fixed).
        for parameter in (model.hidden.bias, *model.out.parameters()):
            parameter.requires_grad_(False)
        mask = torch.zeros_like(model.hidden.weight)
        mask[:, -3:] = 1.0
        model.hidden.weight.register_hook(lambda gradient: gradient * mask)

    def rows(chosen: list[tuple[Episode, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        features = camera_features(model.features, [e for e, _ in chosen])
        previous = np.concatenate([p for _, p in chosen])
        labels = np.concatenate([e.command for e, _ in chosen])
        phases = np.concatenate([e.phase for e, _ in chosen])
        return features, previous, labels, phases

    started = time.perf_counter()
    train_features, train_previous, train_labels, _ = rows(training)
    valid_features, valid_previous, valid_labels, valid_phases = rows(validation)
    if args.without_previous:
        # The control: the same head trained on the same rows with the last command always
        # zero, so its weights stay zero and the network is a reactive one.
        train_previous[:] = 0.0
        valid_previous[:] = 0.0

    def validation_error(previous_scale: float = 1.0) -> float:
        with torch.no_grad():
            out = model.head(torch.from_numpy(valid_features), torch.from_numpy(valid_previous * previous_scale)).numpy()
        return float(row_errors(out, valid_labels).mean())

    start_error = validation_error(0.0)
    optimiser = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=args.lr)
    generator = np.random.default_rng(args.seed)
    history = []
    best = (validation_error(), 0, {k: v.clone() for k, v in model.state_dict().items()})
    features_t, previous_t, labels_t = (torch.from_numpy(a) for a in (train_features, train_previous, train_labels))
    for epoch in range(1, args.epochs + 1):
        model.train()
        order = torch.from_numpy(generator.permutation(len(train_labels)))
        losses = []
        for i in range(0, len(order), args.batch_size):
            index = order[i : i + args.batch_size]
            previous = previous_t[index]
            if args.previous_noise > 0 and not args.without_previous:
                previous = previous + args.previous_noise * torch.from_numpy(generator.standard_normal(previous.shape).astype(np.float32))
            loss = nn.functional.mse_loss(model.head(features_t[index], previous), labels_t[index])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            losses.append(loss.item())
        error = validation_error()
        history.append({"epoch": epoch, "loss": float(np.mean(losses)), "validation_error": error})
        print(f"epoch {epoch}: loss {np.mean(losses):.4f}, validation error {error:.4f}", flush=True)
        if error < best[0]:
            best = (error, epoch, {k: v.clone() for k, v in model.state_dict().items()})
    model.load_state_dict(best[2])
    # How much the network leans on the last command: its error with that input zeroed.
    without = validation_error(0.0)
    align = valid_phases == 2
    with torch.no_grad():
        out = model.head(torch.from_numpy(valid_features), torch.from_numpy(valid_previous)).numpy()
    record = {
        "start": str(args.start),
        "datasets": names,
        "training_seeds": training_seeds,
        "validation_seeds": validation_seeds,
        "epochs": args.epochs,
        "best_epoch": best[1],
        "lr": args.lr,
        "previous_noise": args.previous_noise,
        "without_previous": args.without_previous,
        "only_previous": args.only_previous,
        "validation_error": best[0],
        "start_validation_error": start_error,
        "validation_error_without_previous": without,
        "align_rows_validation_error": float(row_errors(out[align], valid_labels[align]).mean()) if align.any() else None,
        "history": history,
        "wall_s": round(time.perf_counter() - started, 1),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"model": model.state_dict(), "standardise": start.features.standardise_input, "record": record}, args.out)
    args.out.with_suffix(".json").write_text(json.dumps(record, indent=1) + "\n")
    print(json.dumps({k: v for k, v in record.items() if k != "history"}, indent=1))
    return 0


def load_run(path: Path) -> PreviousCommandCNN:
    state = torch.load(path, weights_only=False, map_location="cpu")
    model = PreviousCommandCNN(CameraFeatures())
    model.load_state_dict(state["model"])
    set_standardise(model, bool(state["standardise"]))
    model.eval()
    return model


class Driver:
    """Maps an observation to the command the network sends, with the last one fed back."""

    def __init__(self, model: PreviousCommandCNN, zero_previous: bool = False) -> None:
        self.model = model
        self.zero_previous = zero_previous
        self.previous = np.zeros(3, np.float32)

    def reset(self) -> None:
        self.previous = np.zeros(3, np.float32)

    @torch.no_grad()
    def __call__(self, observation: dict) -> np.ndarray:
        top, bottom = to_network_input(observation["top"], observation["bottom"])
        previous = torch.from_numpy((np.zeros_like(self.previous) if self.zero_previous else self.previous)[None])
        command = sent_commands(self.model(top, bottom, previous).numpy())[0]
        self.previous = command
        return command


def play(args: argparse.Namespace) -> int:
    from .gym_env import NaoDribbleEnv

    torch.set_num_threads(1)
    driver = Driver(load_run(args.run), zero_previous=args.zero_previous)
    out = args.out
    journal = out.with_suffix(".partial.jsonl")
    done = {}
    if journal.is_file():
        for line in journal.read_text().splitlines():
            if line.strip():
                summary = json.loads(line)
                done[summary["seed"]] = summary
    env = NaoDribbleEnv(expert="detector", condition=args.condition)
    try:
        with journal.open("a") as log:
            for seed in tqdm(list(args.seeds), desc=f"{args.run.stem} {args.condition}", unit="episode"):
                if seed in done:
                    continue
                observation, info = env.reset(seed=seed)
                driver.reset()
                while True:
                    observation, _, terminated, truncated, info = env.step(driver(observation))
                    if terminated or truncated:
                        break
                trajectory = info["trajectory"]
                episode = {
                    "seed": seed,
                    "outcome": info["outcome"],
                    "duration_s": info["duration_s"],
                    "computed_commands": info["computed_commands"],
                    "failure": None,
                    "robot": trajectory["robot"],
                    "ball": trajectory["ball"],
                    "heading": trajectory.get("heading"),
                    "first_sighting_s": info.get("first_sighting_s"),
                }
                summary = summarise_episode(episode)
                done[seed] = summary
                log.write(json.dumps(summary) + "\n")
                log.flush()
    finally:
        env.close()
    episodes = [done[s] for s in sorted(done) if s in set(args.seeds)]
    goals = sum(e["outcome"] == "goal" for e in episodes)
    summary = {"engine": "torch (gym, one thread)", "conditions": args.condition, "run": args.run.name, "zero_previous": args.zero_previous, "episodes": episodes}
    out.write_text(json.dumps(summary, indent=1) + "\n")
    misses = [(e["seed"], e["failure_class"]) for e in episodes if e["outcome"] != "goal"]
    print(f"goals {goals} / {len(episodes)} under {args.condition}; misses {misses}")
    return 0


def record_round(args: argparse.Namespace) -> int:
    from .gym_env import NaoDribbleEnv

    refuse_reserved(args.seeds, f"the round {args.out}")
    if not 0.0 <= args.beta <= 1.0:
        raise ValueError(f"--beta {args.beta} is not a probability (0 to 1)")
    torch.set_num_threads(1)
    driver = Driver(load_run(args.run))
    args.out.mkdir(parents=True, exist_ok=True)
    env = NaoDribbleEnv(expert="detector", condition=args.condition)
    executed_expert = 0
    try:
        for seed in tqdm(list(args.seeds), desc=f"round {args.out.name}", unit="episode"):
            target = args.out / f"episode_{seed:05}.npz"
            if target.is_file():
                continue
            mixing = np.random.default_rng(seed)
            observation, info = env.reset(seed=seed)
            driver.reset()
            kept = {"top": [], "bottom": [], "command": [], "phase": [], "previous": []}
            while True:
                kept["top"].append(observation["top"])
                kept["bottom"].append(observation["bottom"])
                kept["command"].append(np.asarray(info["expert_command"], np.float32))
                kept["phase"].append(PHASES.index(info["expert_phase"]))
                kept["previous"].append(driver.previous.copy())
                command = driver(observation)
                if mixing.random() < args.beta:
                    command = sent_commands(np.asarray(info["expert_command"], np.float32)[None])[0]
                    executed_expert += 1
                driver.previous = command
                observation, _, terminated, truncated, info = env.step(command)
                if terminated or truncated:
                    break
            partial = target.with_suffix(".partial.npz")
            np.savez_compressed(
                partial,
                seed=np.int64(seed),
                top=np.stack(kept["top"]),
                bottom=np.stack(kept["bottom"]),
                command=np.stack(kept["command"]),
                phase=np.asarray(kept["phase"], np.uint8),
                previous=np.stack(kept["previous"]).astype(np.float32),
                outcome=np.asarray(info["outcome"]),
            )
            partial.rename(target)
            tqdm.write(f"episode {seed}: {info['outcome']}, {len(kept['phase'])} rows")
    finally:
        env.close()
    print(f"round {args.out}: the teacher's command executed {executed_expert} times (beta {args.beta})")
    return 0


#: The runs of a study directory in the order its table lists them, by file stem prefix.
RUN_ORDER = ("host", "control", "only-previous", "treatment-round", "treatment")


def report(args: argparse.Namespace) -> int:
    """The study's table (README.md in its directory), from the summaries `play` left there
    (`RUN-CONDITION.json`, a condition's `:` as written by `play`)."""
    from collections import Counter

    from .conditions_report import failure_text, interval
    from .eval_summary import class_of

    rows = []
    for path in sorted(args.directory.glob("*.json")):
        summary = json.loads(path.read_text())
        if "episodes" not in summary or "conditions" not in summary:
            continue
        run = Path(summary["run"]).stem
        episodes = summary["episodes"]
        goals = sum(e["outcome"] == "goal" for e in episodes)
        seeds = sorted(e["seed"] for e in episodes)
        failures = Counter(class_of(e) for e in episodes if e["outcome"] != "goal")
        rank = next((i for i, name in enumerate(RUN_ORDER) if run.startswith(name)), len(RUN_ORDER))
        rows.append((summary["conditions"], rank, run, f"{seeds[0]}..{seeds[-1]}", interval(goals, len(episodes)), failure_text(failures)))
    if not rows:
        raise ValueError(f"{args.directory} holds no summary of `play`")
    lines = [
        "# The last command as an input: closed-loop runs",
        "",
        "Generated by `python -m dribble_models.previous_command report` from the summaries beside it; do not edit. "
        "Each run is `previous_command play` (the network in PyTorch, one thread, through the Gymnasium environment); "
        "goals with their Wilson 95 % interval; failure classes as `dribble_models.eval_summary` names them. "
        "docs/src/history/previous-command.md says what each run is.",
        "",
        "| condition | run | seeds | goals (95 % interval) | failures |",
        "|---|---|---|---|---|",
    ]
    for condition, _, run, seeds, goals, failures in sorted(rows):
        lines.append(f"| {condition} | {run} | {seeds} | {goals} | {failures} |")
    (args.directory / "README.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dribble_models.previous_command", description=__doc__.split("\n\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    learn = verbs.add_parser("train", help="the head with the last command as an input, on teacher-driven recordings")
    learn.add_argument("--start", type=Path, required=True, help="a shipped one-network float CNN (models/policy/NAME)")
    learn.add_argument("--dataset", type=Path, action="append", required=True, help="a teacher-driven dribble dataset (repeatable)")
    learn.add_argument("--round", type=Path, action="append", default=[], help="a `round` directory whose rows join the training rows (repeatable)")
    learn.add_argument("--out", type=Path, required=True, help="the run's weights (.pt; a .json record beside)")
    learn.add_argument("--epochs", type=int, default=8)
    learn.add_argument("--lr", type=float, default=3e-4)
    learn.add_argument("--batch-size", type=int, default=64)
    learn.add_argument("--previous-noise", type=float, default=0.1, help="Gaussian noise on the last command in training, normalised units")
    learn.add_argument("--without-previous", action="store_true", help="the control: the last command always zero (a reactive head trained on the same rows)")
    learn.add_argument("--only-previous", action="store_true", help="train only the last command's weights into the hidden layer (the start's head otherwise kept)")
    learn.add_argument("--validation-episodes", type=int, default=3)
    learn.add_argument("--seed", type=int, default=0)
    learn.add_argument("--threads", type=int, default=1)
    run = verbs.add_parser("play", help="closed loop in the Gymnasium environment, the command sent fed back")
    run.add_argument("run", type=Path, help="a run's weights (.pt)")
    run.add_argument("--seeds", type=seed_range, required=True, metavar="A..B")
    run.add_argument("--condition", default="clean", help="clean, NAME:SEVERITY or randomized")
    run.add_argument("--zero-previous", action="store_true", help="feed zero as the last command (the network without its second input)")
    run.add_argument("--out", type=Path, required=True, help="the summary (JSON); a journal beside resumes a cut run")
    mix = verbs.add_parser("round", help="a DAgger round: the network drives, the teacher labels, the executed command kept")
    mix.add_argument("run", type=Path, help="a run's weights (.pt)")
    mix.add_argument("--seeds", type=seed_range, required=True, metavar="A..B", help="DAgger seeds (1000..9999)")
    mix.add_argument("--condition", default="randomized", help="clean, NAME:SEVERITY or randomized")
    mix.add_argument("--beta", type=float, default=0.3, help="probability of executing the teacher's command instead, per computed command")
    mix.add_argument("--out", type=Path, required=True, help="a directory of episode_*.npz (a cut round resumes)")
    table = verbs.add_parser("report", help="the table of a directory of `play` summaries (its README.md)")
    table.add_argument("directory", type=Path)
    args = parser.parse_args(argv)
    try:
        return {"train": train, "play": play, "round": record_round, "report": report}[args.verb](args)
    except (DatasetError, OSError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
