"""The labels of `--distill-from`: the commands a shipped float CNN sends for each training
row (on its clean twin where one was recorded), and with `--distill-camera-clean` only on the
rows it sees as it learned to, the teacher's elsewhere."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from .command_metric import sent_commands
from .dataset import DatasetError, Episode
from .networks import CNN, PAPER_FILTERS
from .prediction import to_input
from .shipped_weights import ShippedWeightsError, is_shipped_model, load_shipped_weights

if TYPE_CHECKING:
    from .train import TrainingConfig


def distilled_commands(model_path: Path, episodes: list[Episode], device: torch.device | str = "cpu", chunk: int = 512) -> list[np.ndarray]:
    """The commands the shipped float CNN at `model_path` sends for each row of `episodes`,
    one array an episode: the labels of `--distill-from`. An episode recorded with a clean
    twin (`dribble record --clean-twin`) is shown its twin's thumbnails: what a
    clean-trained model sees of the same state."""
    if not is_shipped_model(model_path):
        raise DatasetError(f"--distill-from {model_path}: not a shipped model (a directory with policy.toml)")
    teacher = CNN(PAPER_FILTERS)
    try:
        load_shipped_weights(teacher, model_path, "cnn")
    except ShippedWeightsError as error:
        raise DatasetError(f"--distill-from: {error}") from error
    teacher.to(device).eval()
    out = []
    with torch.no_grad():
        for episode in episodes:
            tops, bottoms = (episode.top_clean, episode.bottom_clean) if episode.has_clean_twin else (episode.top, episode.bottom)
            commands = np.empty_like(episode.command)
            for start in range(0, len(commands), chunk):
                end = min(start + chunk, len(commands))
                top, bottom = to_input(tops[start:end], device), to_input(bottoms[start:end], device)
                commands[start:end] = sent_commands(teacher(top, bottom).cpu().numpy())
            out.append(commands)
    return out


#: Conditions under which a camera sees as on a clean render: robots around the field change
#: the scene but neither the camera, the light nor the venue.
CAMERA_CLEAN_CONDITIONS = {"clean", "robots"}


def camera_clean(episode: Episode) -> bool:
    """Whether `episode` was recorded with nothing that changes how the camera sees (no
    camera, light or venue condition): where a policy trained on clean renders sees as it
    was trained to, so `--distill-camera-clean` takes its commands there."""
    names = {part.split(":")[0] for part in (episode.conditions or "clean").split(",")}
    return names <= CAMERA_CLEAN_CONDITIONS


def seen_clean(episode: Episode) -> bool:
    """Whether a clean-trained policy can see `episode`'s states as it learned to: the
    episode is camera-clean, or it was recorded with a clean twin of every frame."""
    return camera_clean(episode) or episode.has_clean_twin


def distilled_labels(args: TrainingConfig, episodes: list[Episode], device: torch.device | str) -> list[np.ndarray]:
    """The labels `--distill-from` gives `episodes`, one array an episode: the distilled
    model's commands (on clean twins where recorded); with `--distill-camera-clean` only
    where it sees as it learned to, the teacher's elsewhere."""
    distilled = distilled_commands(args.distill_from, episodes, device)
    if not args.distill_camera_clean:
        return distilled
    rows = sum(len(e) for e in episodes)
    clean = sum(len(e) for e in episodes if seen_clean(e))
    twinned = sum(len(e) for e in episodes if e.has_clean_twin and not camera_clean(e))
    print(
        f"distilled labels on {clean} of {rows} rows (camera-clean episodes; "
        f"{twinned} of them conditioned rows labelled from their clean twins)",
        file=sys.stderr,
    )
    return [labels if seen_clean(e) else e.command for labels, e in zip(distilled, episodes)]
