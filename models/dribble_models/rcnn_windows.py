"""The R-CNN's training in windows (truncated back-propagation through time): whole episodes
dealt into parallel lanes, each lane's next window per step, its targets and mask, and the
loss over the real rows; and one episode run through the network the same way."""

from __future__ import annotations

import numpy as np
import torch

from .dataset import Episode
from .networks import RCNN


def rcnn_forward_windows(model: RCNN, top: torch.Tensor, bottom: torch.Tensor, window: int) -> torch.Tensor:
    """One episode [T,1,H,W] through the R-CNN in windows of `window` steps, the state carried
    from window to window (detached, as in training) and zero at the start: [T,3]."""
    state = model.zero_state()
    outputs = []
    for start in range(0, top.shape[0], window):
        out, state = model(top[None, start : start + window], bottom[None, start : start + window], state)
        state = (state[0].detach(), state[1].detach())
        outputs.append(out[0])
    return torch.cat(outputs)


def lanes_of(episodes: list[Episode], order: np.ndarray, lanes: int) -> list[list[int]]:
    """Episodes (in `order`) dealt into lanes of nearly equal total length."""
    result: list[list[int]] = [[] for _ in range(lanes)]
    totals = [0] * lanes
    for e in order:
        lane = int(np.argmin(totals))
        result[lane].append(int(e))
        totals[lane] += len(episodes[e])
    return result


def window_schedule(episodes: list[Episode], lanes: list[list[int]], window: int) -> list[list[tuple[int, int] | None]]:
    """Per training step, per lane: (episode, first row) of its next window, or None."""
    per_lane = [[(e, s) for e in lane for s in range(0, len(episodes[e]), window)] for lane in lanes]
    steps = max((len(l) for l in per_lane), default=0)
    return [[l[t] if t < len(l) else None for l in per_lane] for t in range(steps)]


def lanes_in(step: list[tuple[int, int] | None]):
    """The lanes of one training step that hold a window: (lane, (episode, first row))."""
    return [(lane, item) for lane, item in enumerate(step) if item is not None]


def window_targets(step, episodes: list[Episode], window: int, lanes: int, device: torch.device | str = "cpu"):
    """For one step's windows, on `device`: the expert's commands [lanes, window, 3], the mask
    of real rows [lanes, window], and the factor [1, lanes, 1] that zeroes the carried state
    of a lane whose window starts an episode (as on the robot)."""
    target = torch.zeros(lanes, window, 3)
    mask = torch.zeros(lanes, window)
    fresh = torch.ones(1, lanes, 1)
    for lane, (e, start) in lanes_in(step):
        end = min(start + window, len(episodes[e]))
        target[lane, : end - start] = torch.from_numpy(episodes[e].command[start:end])
        mask[lane, : end - start] = 1.0
        if start == 0:
            fresh[0, lane, 0] = 0.0
    return target.to(device), mask.to(device), fresh.to(device)


def masked_loss(out: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean squared error over the real rows of the windows."""
    squared = ((out - target) ** 2).mean(dim=2)
    return (squared * mask).sum() / mask.sum().clamp(min=1.0)
