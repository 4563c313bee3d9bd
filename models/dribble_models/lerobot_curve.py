"""A LeRobot policy's learning curve, in dribble's own terms.

    scripts/lerobot curve RUN --dataset DIR --seeds 54..60 --out FILE.json [--plot FILE.png]
        [--reference models/policy/NAME]

`RUN` is a `lerobot-train` output directory (`scripts/lerobot train-act ROOT RUN`). Two
curves come out of it:

- **Training loss**, LeRobot's own: the `step:N ... loss:X grdn:G lr:R updt_s:U` lines its
  trainer logs every `--log_freq` steps, read from the log `scripts/lerobot train-act` keeps
  beside the run (`RUN.log`, or `--log`).
- **Validation error**, dribble's metric (`command_metric.row_errors`: the Euclidean distance between
  the command sent, clamped to [-1, 1], and the teacher's, averaged over rows), of every
  checkpoint the trainer saved (`RUN/checkpoints/<step>/pretrained_model`) on the rows of the
  held-out episodes of a dribble dataset. The checkpoint runs as `scripts/lerobot eval` plays
  it: LeRobot's own saved pre- and post-processors around the policy, the first command of
  each predicted chunk sent (the exports' `n_action_steps` of 1). The seeds must be episodes
  the run never trained on: the ones its export held out, or a recording beside it.

The last checkpoint's forward pass is timed too (`forward`: one command as the closed loop
asks for it, on one thread), the figure to hold against the robot's tick.

`--training-dataset` scores one constant command beside them, the median of the rows the run
trained on: a checkpoint no better than it has not yet learned to read its images.

`--reference` adds a shipped dribble model's validation error on the same seeds (its
manifest's `validation_error` when its `validation_seeds` are these, else computed with
onnxruntime as the controller would run it) as a line in the plot. Each checkpoint's error is
kept in the JSON, so running it again scores only new checkpoints. Runs only in LeRobot's
environment (`scripts/lerobot`); reading the trainer's log needs only the project's.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import time
import tomllib
from pathlib import Path
from typing import Callable

import numpy as np

from .cluster import seed_range
from .dataset import Episode, load
from .command_metric import row_errors

#: One line of LeRobot's trainer log (`lerobot/scripts/lerobot_train.py`, `MetricsTracker`).
LOG_LINE = re.compile(
    r"step:(?P<step>[0-9.]+[KMB]?) smpl:(?P<samples>[0-9.]+[KMB]?) ep:\S+ epch:(?P<epoch>[0-9.]+) "
    r"loss:(?P<loss>[0-9.e+-]+) grdn:(?P<grad_norm>[0-9.e+-]+) lr:(?P<lr>[0-9.e+-]+) updt_s:(?P<update_s>[0-9.]+)"
)
ROWS_PER_BATCH = 64


def count(text: str) -> int:
    """LeRobot's short counts ("2K", "1.5M") as integers."""
    scale = {"K": 1_000, "M": 1_000_000, "B": 1_000_000_000}.get(text[-1], 1)
    return round(float(text.rstrip("KMB")) * scale)


#: The trainer's progress bar (`Training:  25%|...| 10/40 [...]`): the exact step, where the
#: log line itself rounds it ("step:1K" from 1,000 to 1,499).
PROGRESS = re.compile(r"\| *(?P<step>[0-9]+)/(?P<total>[0-9]+) \[")
#: What the trainer logs at each start: the run's whole length. A resumed run's bar counts the
#: steps left (`50/16500` at step 3,550 of 20,000).
CONFIGURED_STEPS = re.compile(r"cfg\.steps=(?P<steps>[0-9]+)")


def training_log(log: Path) -> list[dict]:
    """The trainer's logged steps, in order; a resumed run's repeated steps keep the last.
    A line's step is that of the progress bar drawn on the same line before it (past the
    steps a resumed run had done before its start), else the line's own rounded one."""
    text = log.read_text(errors="replace")
    steps: dict[int, dict] = {}
    for found in LOG_LINE.finditer(text):
        # The bar LeRobot drew on the same line (tqdm redraws with carriage returns).
        line_start = text.rfind("\n", 0, found.start()) + 1
        bars = list(PROGRESS.finditer(text, line_start, found.start()))
        if bars:
            starts = list(CONFIGURED_STEPS.finditer(text, 0, found.start()))
            configured = int(starts[-1]["steps"]) if starts else int(bars[-1]["total"])
            step = int(bars[-1]["step"]) + configured - int(bars[-1]["total"])
        else:
            step = count(found["step"])
        steps[step] = {
            "step": step,
            "samples": count(found["samples"]),
            "epoch": float(found["epoch"]),
            "loss": float(found["loss"]),
            "grad_norm": float(found["grad_norm"]),
            "lr": float(found["lr"]),
            "update_s": float(found["update_s"]),
        }
    return [steps[s] for s in sorted(steps)]


def checkpoints(run: Path) -> list[tuple[int, Path]]:
    """(step, pretrained_model directory) of every numbered checkpoint of `run`."""
    found = []
    for directory in sorted((run / "checkpoints").glob("[0-9]*")):
        model = directory / "pretrained_model"
        if directory.name.isdigit() and (model / "model.safetensors").is_file():
            found.append((int(directory.name), model))
    return found


def batch_of(episode: Episode, rows: slice) -> dict:
    """Rows of an episode as LeRobot's environment wrapper (`lerobot_eval.LeRobotObservations`)
    hands them to the preprocessor: the thumbnails' luma in three equal channels, float in
    [0, 1], and the exports' two-zero state."""
    import torch

    from .lerobot_eval import BOTTOM, STATE, STATE_SIZE, TOP

    def image(frames: np.ndarray):
        values = torch.from_numpy(frames[rows].astype(np.float32) / 255.0)
        return values[:, None].expand(-1, 3, -1, -1).contiguous()

    top = image(episode.top)
    return {TOP: top, BOTTOM: image(episode.bottom), STATE: torch.zeros(top.shape[0], STATE_SIZE)}


def loaded(model: Path) -> tuple:
    """A checkpoint's (policy, preprocessor, postprocessor), on the CPU, as `scripts/lerobot
    eval` plays it."""
    from .lerobot_eval import policy_and_processors

    policy, preprocessor, postprocessor, _ = policy_and_processors(model)
    return policy, preprocessor, postprocessor


def commands(checkpoint: tuple, episode: Episode) -> np.ndarray:
    """The command a `loaded` checkpoint sends on each row of `episode` (the first of its chunk)."""
    import torch

    policy, preprocessor, postprocessor = checkpoint
    sent = []
    with torch.no_grad():
        for start in range(0, len(episode.command), ROWS_PER_BATCH):
            batch = preprocessor(batch_of(episode, slice(start, start + ROWS_PER_BATCH)))
            chunk = policy.predict_action_chunk(batch)
            sent.append(postprocessor(chunk[:, 0]).cpu().numpy())
    return np.concatenate(sent).astype(np.float32)


def forward_ms(model: Path, episode: Episode, rows: int = 60, warm_up: int = 10) -> dict:
    """One command as the closed loop asks for it (a reset, LeRobot's `select_action` on one
    row through the saved processors), on one thread: the median and the 90th percentile over
    `rows` rows after `warm_up`, milliseconds. Beside it the robot's tick is about 2 ms."""
    import torch

    torch.set_num_threads(1)
    policy, preprocessor, postprocessor = loaded(model)
    times = []
    with torch.no_grad():
        for row in range(min(rows + warm_up, len(episode.command))):
            batch = batch_of(episode, slice(row, row + 1))
            started = time.perf_counter()
            policy.reset()
            postprocessor(policy.select_action(preprocessor(batch)))
            times.append(time.perf_counter() - started)
    kept = times[warm_up:] or times
    return {"median_ms": round(1e3 * statistics.median(kept), 2), "p90_ms": round(1e3 * float(np.percentile(kept, 90)), 2), "rows": len(kept), "threads": 1}


def validation_error(model: Path, episodes: list[Episode]) -> dict:
    """dribble's validation error of a LeRobot checkpoint on `episodes`."""
    checkpoint = loaded(model)
    sent = [commands(checkpoint, e) for e in episodes]
    errors = [row_errors(c, e.command) for c, e in zip(sent, episodes)]
    every = np.concatenate(errors)
    # How much its commands vary from row to row beside the teacher's: a policy that does not
    # yet read its images sends nearly the same command everywhere.
    spread = np.concatenate(sent).std(axis=0)
    teacher = np.concatenate([e.command for e in episodes]).std(axis=0)
    return {
        "error": float(every.mean()),
        "rows": int(len(every)),
        "episodes": {e.seed: float(r.mean()) for e, r in zip(episodes, errors)},
        "command_spread": [round(float(v), 4) for v in spread],
        "teacher_spread": [round(float(v), 4) for v in teacher],
    }


def reference_error(policy: Path, episodes: list[Episode], seeds: list[int]) -> dict:
    """A shipped model's validation error on the same rows: its manifest's where it was
    validated on exactly these seeds, else onnxruntime on them (the manifest's normalisation)."""
    manifest_path = policy / "policy.toml" if policy.is_dir() else policy
    manifest = tomllib.loads(manifest_path.read_text())
    training = manifest.get("training", {})
    if sorted(training.get("validation_seeds", [])) == seeds and "validation_error" in training:
        return {"policy": manifest_path.parent.name, "error": float(training["validation_error"]), "from": "its manifest"}
    from .gym_equivalence import OnnxPolicy

    network = OnnxPolicy(manifest_path)
    errors = [row_errors(np.stack([network({"top": t, "bottom": b}) for t, b in zip(e.top, e.bottom)]), e.command) for e in episodes]
    return {"policy": manifest_path.parent.name, "error": float(np.concatenate(errors).mean()), "from": "onnxruntime on the rows"}


def constant_error(training: Path, episodes: list[Episode]) -> dict:
    """The error of one constant command, the training rows' per-component median, on the
    held-out rows: what a network that has not yet learned to read its images scores. Where
    the training dataset also holds the held-out episodes (an export's whole source, split
    by its `info.json`), they take no part in the median."""
    held_out = {e.seed for e in episodes}
    rows = [e.command for e in load(training).episodes if e.seed not in held_out]
    if not rows:
        raise ValueError(f"{training}: no episodes besides the held-out ones to take a constant command from")
    command = np.median(np.concatenate(rows), axis=0)
    errors = np.concatenate([row_errors(np.repeat(command[None], len(e.command), axis=0), e.command) for e in episodes])
    return {"command": [round(float(c), 4) for c in command], "error": float(errors.mean()), "training": str(training)}


def plot(summary: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, loss_axis = plt.subplots(figsize=(7.5, 4.8))
    log = summary["training"]
    if log:
        loss_axis.plot([s["step"] for s in log], [s["loss"] for s in log], color="tab:blue", alpha=0.6, label="training loss (LeRobot's)")
    loss_axis.set_xlabel("training step (batch of %d)" % summary.get("batch_size", 0))
    loss_axis.set_ylabel("training loss", color="tab:blue")
    error_axis = loss_axis.twinx()
    curve = summary["checkpoints"]
    if curve:
        error_axis.plot([c["step"] for c in curve], [c["error"] for c in curve], "s-", color="tab:red", label="validation error")
    reference = summary.get("reference")
    if reference:
        error_axis.axhline(reference["error"], color="tab:green", linestyle="--", label=f"{reference['policy']} (validation error)")
    constant = summary.get("constant")
    if constant:
        error_axis.axhline(constant["error"], color="tab:gray", linestyle=":", label="one constant command (the training rows' median)")
    error_axis.set_ylabel(f"validation error, seeds {summary['seeds']} (dribble's metric)", color="tab:red")
    error_axis.set_ylim(bottom=0)
    handles = loss_axis.get_legend_handles_labels()[0] + error_axis.get_legend_handles_labels()[0]
    labels = loss_axis.get_legend_handles_labels()[1] + error_axis.get_legend_handles_labels()[1]
    figure.legend(handles, labels, loc="lower center", ncol=2, fontsize=8, frameon=False)
    loss_axis.set_title(summary["title"], fontsize=9)
    figure.tight_layout(rect=(0, 0.11, 1, 1))
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=110)
    plt.close(figure)


def curve(
    run: Path,
    log: Path,
    dataset: Path,
    seeds: range,
    reference: Path | None,
    kept: dict | None,
    training: Path | None = None,
    progress: Callable[[dict], None] | None = None,
) -> dict:
    episodes = load(dataset, require_seeds=list(seeds)).episodes
    episodes = [e for e in episodes if e.seed in seeds]
    held_out = f"{seeds.start}..{seeds.stop - 1}"
    scored = {c["step"]: c for c in (kept or {}).get("checkpoints", []) if kept and kept.get("seeds") == held_out}
    for step, model in checkpoints(run):
        if step not in scored:
            started = time.monotonic()
            scored[step] = {"step": step, **validation_error(model, episodes), "seconds": round(time.monotonic() - started, 1)}
            print(f"step {step}: validation error {scored[step]['error']:.4f}", file=sys.stderr)
            if progress is not None:
                progress({"seeds": held_out, "checkpoints": [scored[s] for s in sorted(scored)]})
    # The trainer's configuration where it saved one (the policy's own config.json else).
    config, policy = {}, {}
    last = checkpoints(run)
    if last and (last[-1][1] / "train_config.json").is_file():
        config = json.loads((last[-1][1] / "train_config.json").read_text())
        policy = config.get("policy", {})
    elif last:
        policy = json.loads((last[-1][1] / "config.json").read_text())
    summary = {
        "run": str(run),
        "title": f"LeRobot {policy.get('type', '?')} ({policy.get('vision_backbone', '?')}, lr {policy.get('optimizer_lr', '?')}) on {Path(config.get('dataset', {}).get('root', '?')).name}",
        "dataset": str(dataset),
        "seeds": held_out,
        "batch_size": config.get("batch_size"),
        "training": training_log(log) if log.is_file() else [],
        "checkpoints": [scored[s] for s in sorted(scored)],
    }
    if last:
        summary["forward"] = {"step": last[-1][0], **forward_ms(last[-1][1], episodes[0])}
    if training is not None:
        summary["constant"] = constant_error(training, episodes)
    if reference is not None:
        summary["reference"] = (kept or {}).get("reference") or reference_error(reference, episodes, list(seeds))
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/lerobot curve", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a lerobot-train output directory (scripts/lerobot train-act ROOT RUN)")
    parser.add_argument("--log", type=Path, help="the trainer's log (default RUN.log, which scripts/lerobot train-act writes)")
    parser.add_argument("--dataset", type=Path, required=True, help="a dribble dataset holding the held-out episodes")
    parser.add_argument("--seeds", type=seed_range, required=True, metavar="A..B", help="the held-out episodes' seeds, A to B - 1")
    parser.add_argument("--reference", type=Path, help="a shipped model (models/policy/NAME) whose validation error on the same seeds is drawn beside")
    parser.add_argument("--training-dataset", type=Path, help="the dribble dataset the run was trained on: one constant command, its rows' median, is scored beside")
    parser.add_argument("--out", type=Path, required=True, help="the curve (JSON); checkpoints already in it are not scored again")
    parser.add_argument("--plot", type=Path, help="the curve as a picture (PNG)")
    args = parser.parse_args(argv)
    if not (args.run / "checkpoints").is_dir():
        parser.error(f"{args.run} has no checkpoints/: not a lerobot-train output directory")
    # Each checkpoint scored is kept in OUT.partial as it ends (scoring one takes minutes on
    # a CPU), so a run cut off goes on from there.
    partial = args.out.with_name(args.out.name + ".partial")
    kept = next((json.loads(p.read_text()) for p in (args.out, partial) if p.is_file()), None)
    log = args.log or args.run.with_name(args.run.name + ".log")
    args.out.parent.mkdir(parents=True, exist_ok=True)

    def keep(scored: dict) -> None:
        partial.write_text(json.dumps({**(kept or {}), **scored}, indent=1) + "\n")

    summary = curve(args.run, log, args.dataset, args.seeds, args.reference, kept, args.training_dataset, keep)
    args.out.write_text(json.dumps(summary, indent=1) + "\n")
    partial.unlink(missing_ok=True)
    if args.plot:
        plot(summary, args.plot)
    for c in summary["checkpoints"]:
        print(f"step {c['step']}: validation error {c['error']:.4f} on {c['rows']} rows")
    return 0


if __name__ == "__main__":
    sys.exit(main())
