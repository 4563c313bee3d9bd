"""A start for `--standardise-input` from a model trained on `pixel / 255`: its first
convolutions re-expressed at the training rows' typical level and spread."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import nn

from . import contract
from .networks import CameraFeatures

if TYPE_CHECKING:
    from .train import Rows


def typical_level(thumbnails: np.ndarray, sample: np.ndarray) -> tuple[float, float]:
    """The mean over `sample` rows of each thumbnail's own mean and spread, in pixel levels."""
    pixels = thumbnails[sample].astype(np.float64)
    means = pixels.mean(axis=(1, 2))
    spreads = np.maximum(pixels.std(axis=(1, 2)), contract.STANDARDISE_FLOOR_LEVELS)
    return float(means.mean()), float(spreads.mean())


@torch.no_grad()
def fold_typical_level(model: nn.Module, rows: Rows, rng: np.random.Generator, sample_rows: int = 4096) -> None:
    """Re-expresses the first convolution of each camera branch of a model trained on
    `pixel / 255` for standardised input: with a thumbnail's typical mean `m` and spread `s`,
    `pixel / 255 = (z * s + m) / 255`, so `W' = W * s / 255` and `b' = b + sum(W) * m / 255`
    give the old first layer's answer on a typical thumbnail (exactly where mean and spread
    are typical, away from the zero-padded border). A start, not an equivalence: training
    then learns the rest."""
    sample = np.sort(rng.choice(len(rows.top), size=min(sample_rows, len(rows.top)), replace=False))
    for module in model.modules():
        if not isinstance(module, CameraFeatures):
            continue
        for branch, thumbnails in ((module.top, rows.top), (module.bottom, rows.bottom)):
            mean, spread = typical_level(thumbnails, sample)
            first = branch[0]
            scale = float(contract.INPUT_SCALE)
            first.bias += first.weight.sum(dim=(1, 2, 3)) * (mean * scale)
            first.weight *= spread * scale
