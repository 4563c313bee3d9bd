"""A network's commands for recorded rows, each kind run as the controller runs it: the CNN
one row at a time (with the command executed before where it reads one), the H-CNN through
its gating, the R-CNN over a whole episode from a zero state; and the paper's error of those
commands over episodes. Used by the trainer (validation, scores) and by the distillation."""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from . import contract
from .command_metric import row_errors
from .dataset import PHASES, Episode
from .networks import CNN, HCNN, RCNN, ModalCNN, PreviousCommandCNN

SCALE = np.float32(contract.INPUT_SCALE)


def score(predictions: list[np.ndarray], episodes: list[Episode]) -> dict:
    """The error overall, per expert phase and per episode."""
    errors = [row_errors(p, e.command) for p, e in zip(predictions, episodes)]
    every = np.concatenate(errors) if errors else np.zeros(0)
    phases = np.concatenate([e.phase for e in episodes]) if episodes else np.zeros(0, np.uint8)
    per_phase = {}
    for index, name in enumerate(PHASES):
        chosen = every[phases == index]
        per_phase[name] = {"error": float(chosen.mean()) if len(chosen) else None, "rows": int(len(chosen))}
    return {
        "error": float(every.mean()) if len(every) else math.nan,
        "rows": int(len(every)),
        "phases": per_phase,
        "episodes": [{"seed": e.seed, "error": float(r.mean()), "rows": len(r)} for e, r in zip(episodes, errors)],
    }


def to_input(thumbnails: np.ndarray, device: torch.device | str = "cpu") -> torch.Tensor:
    """u8 [N,H,W] -> f32 [N,1,H,W] on `device`, `pixel * scale` as the robot computes it."""
    return (torch.from_numpy(np.asarray(thumbnails)).unsqueeze(1).float() * torch.tensor(SCALE)).to(device)


def gating_features(top: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """The 10-value H-CNN feature of many rows at once: `numpy.histogram(x, 5, (0, 255))`
    of each thumbnail over its pixel count, top then bottom (gating.py, one row at a time)."""

    def histograms(images: np.ndarray) -> np.ndarray:
        bins = np.minimum(images.reshape(len(images), -1) // 51, 4)
        counts = np.stack([(bins == b).sum(axis=1) for b in range(contract.HISTOGRAM_BINS)], axis=1)
        return (counts / bins.shape[1]).astype(np.float32)

    return np.concatenate([histograms(top), histograms(bottom)], axis=1)


def nearest(features: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """Nearest centroid (Euclidean, in f32 like the robot), the first on a tie."""
    distances = np.linalg.norm(features[:, None, :] - centroids[None, :, :].astype(np.float32), axis=2)
    return np.argmin(distances, axis=1)


def device_of(model: nn.Module) -> torch.device:
    """Where `model`'s weights are (the CPU or a GPU)."""
    return next(model.parameters()).device


@torch.no_grad()
def predict_cnn(model: CNN | ModalCNN | PreviousCommandCNN, episode: Episode, chunk: int = 512) -> np.ndarray:
    """Each row's command; a network that reads its last command is given the command the
    recording executed at the row before (`Episode.previous`), as the controller would feed
    it on the robot that drove the episode."""
    model.eval()
    device = device_of(model)

    def rows(i: int) -> tuple[torch.Tensor, ...]:
        images = (to_input(episode.top[i : i + chunk], device), to_input(episode.bottom[i : i + chunk], device))
        if isinstance(model, PreviousCommandCNN):
            return (*images, torch.from_numpy(episode.previous[i : i + chunk]).to(device))
        return images

    out = [model(*rows(i)).cpu().numpy() for i in range(0, len(episode), chunk)]
    return np.concatenate(out) if out else np.zeros((0, 3), np.float32)


@torch.no_grad()
def predict_hcnn(model: HCNN, episode: Episode, chunk: int = 512) -> np.ndarray:
    model.eval()
    device = device_of(model)
    clusters = nearest(gating_features(episode.top, episode.bottom), model.centroids)
    out = np.zeros((len(episode), 3), np.float32)
    for k, expert in enumerate(model.experts):
        rows = np.flatnonzero(clusters == k)
        for i in range(0, len(rows), chunk):
            part = rows[i : i + chunk]
            out[part] = expert(to_input(episode.top[part], device), to_input(episode.bottom[part], device)).cpu().numpy()
    return out


@torch.no_grad()
def predict_rcnn(model: RCNN, episode: Episode, chunk: int = 512) -> np.ndarray:
    """The whole episode from a zero state, as the controller steps it."""
    model.eval()
    device = device_of(model)
    features = torch.cat(
        [model.features(to_input(episode.top[i : i + chunk], device), to_input(episode.bottom[i : i + chunk], device)) for i in range(0, len(episode), chunk)]
    )
    out, _ = model.lstm(features.unsqueeze(0), model.zero_state())
    return model.head(out[0]).cpu().numpy()


def predict(model, kind: str, episodes: list[Episode]) -> list[np.ndarray]:
    step = {"cnn": predict_cnn, "hcnn": predict_hcnn, "rcnn": predict_rcnn}[kind]
    return [step(model, e) for e in episodes]


@torch.no_grad()
def episode_features(model: RCNN, episode: Episode, chunk: int = 512) -> torch.Tensor:
    """An episode's camera features [T, FEATURES] (the frozen convolutions, once), kept on the CPU."""
    model.features.eval()
    device = device_of(model)
    return torch.cat(
        [
            model.features(to_input(episode.top[i : i + chunk], device), to_input(episode.bottom[i : i + chunk], device)).cpu()
            for i in range(0, len(episode), chunk)
        ]
    )
