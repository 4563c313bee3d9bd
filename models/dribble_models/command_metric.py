"""dribble's command error, the paper's metric: the Euclidean distance between the command
the controller sends for a network's raw output and the teacher's. Apart from the trainer so
that environments without its dependencies (LeRobot's) score by the same rule."""

from __future__ import annotations

import numpy as np


def sent_commands(prediction: np.ndarray) -> np.ndarray:
    """What the controller publishes for raw outputs [N,3]: each component clamped to
    [-1, 1]; a row with a non-finite component becomes a stop."""
    prediction = np.asarray(prediction, dtype=np.float32)
    finite = np.all(np.isfinite(prediction), axis=1, keepdims=True)
    return np.where(finite, np.clip(np.nan_to_num(prediction), -1.0, 1.0), 0.0).astype(np.float32)


def row_errors(prediction: np.ndarray, expert: np.ndarray) -> np.ndarray:
    """Per-row Euclidean distance between the sent command and the expert's, float64."""
    difference = sent_commands(prediction).astype(np.float64) - np.asarray(expert, np.float64)
    return np.sqrt(np.sum(difference * difference, axis=1))
