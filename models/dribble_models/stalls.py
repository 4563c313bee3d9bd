"""Stalled stretches of a policy-driven episode, cut short before they reach training.

A DAgger round lets the learned policy drive. Where it stands (or turns on the spot) and its
images stop changing, it stays so until the 90 s limit: one such episode adds up to 2,700
near-identical rows, more than a whole successful episode, and a round with a few of them
is mostly one state. The teacher's label there is worth learning (it says which way to turn),
but not 2,700 times.

Two ways were open (issue 28): the teacher takes over after a few seconds without progress
(HG-DAgger, Kelly et al. 2019), or the repeated rows are thinned. This module thins, by
cutting: a row is *stalled* when, over the `after_s` seconds up to it, the robot moved less
than `moved_m`, turned less than `turned_rad` and the ball moved less than `moved_m`. The
first `after_s` seconds of a stall are kept (those rows are not stalled by this rule: their
window still reaches back before the stall began); the rest are dropped until the robot or
the ball moves again. Cutting was chosen because it leaves the recorded rounds exactly as
the policy drove them (the evaluation of a round, its failure classes and its videos stay
those of the policy) and needs no change to the simulator; a takeover would change the
states a round visits. What remains of an episode comes back as contiguous pieces, so the
R-CNN trains on unbroken windows (each piece starts from a zero state, as a new episode).

Applied to the policy-driven rounds only: the teacher's own demonstrations do not stall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dataset import Episode


@dataclass(frozen=True)
class StallRule:
    """When a row counts as stalled (see the module's documentation)."""

    after_s: float = 3.0
    moved_m: float = 0.05
    turned_rad: float = 0.15


def stalled_rows(episode: Episode, rule: StallRule) -> np.ndarray:
    """A boolean mask over the episode's rows: True where the row is stalled by `rule`.

    An episode recorded without poses (older datasets) has no stalled rows."""
    if episode.robot_pose is None or episode.ball is None or episode.time_s is None:
        return np.zeros(len(episode), dtype=bool)
    time_s = np.asarray(episode.time_s, dtype=np.float64)
    pose = np.asarray(episode.robot_pose, dtype=np.float64)
    ball = np.asarray(episode.ball, dtype=np.float64)
    stalled = np.zeros(len(episode), dtype=bool)
    first = 0
    for row in range(len(episode)):
        # The window is the rows within after_s before this one, this one included.
        while time_s[row] - time_s[first] > rule.after_s:
            first += 1
        if first == 0 and time_s[row] - time_s[0] < rule.after_s:
            continue  # less than after_s of history: nothing can have stalled that long yet
        window = slice(first, row + 1)
        moved = np.hypot(*(pose[window, :2] - pose[row, :2]).T).max()
        turned = np.abs(np.angle(np.exp(1j * (pose[window, 2] - pose[row, 2])))).max()
        ball_moved = np.hypot(*(ball[window] - ball[row]).T).max()
        stalled[row] = moved < rule.moved_m and turned < rule.turned_rad and ball_moved < rule.moved_m
    return stalled


def cut_stalls(episode: Episode, rule: StallRule) -> list[Episode]:
    """The episode without its stalled rows, as contiguous pieces in order."""
    keep = ~stalled_rows(episode, rule)
    if keep.all():
        return [episode]
    pieces = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
    for start, end in zip(edges[::2], edges[1::2]):
        pieces.append(episode.rows(start, end))
    return pieces


@dataclass(frozen=True)
class CutReport:
    """What cutting did to a set of episodes."""

    rows_before: int
    rows_after: int
    episodes_cut: int

    def describe(self) -> str:
        dropped = self.rows_before - self.rows_after
        share = dropped / self.rows_before if self.rows_before else 0.0
        return f"{dropped} stalled rows ({share:.1%}) cut from {self.episodes_cut} episodes"


def cut_all(episodes: list[Episode], rule: StallRule) -> tuple[list[Episode], CutReport]:
    """Every episode's pieces, and how many rows were dropped."""
    pieces: list[Episode] = []
    cut = 0
    for episode in episodes:
        kept = cut_stalls(episode, rule)
        cut += int(sum(len(p) for p in kept) < len(episode))
        pieces.extend(kept)
    report = CutReport(sum(len(e) for e in episodes), sum(len(p) for p in pieces), cut)
    return pieces, report


__all__ = ["StallRule", "stalled_rows", "cut_stalls", "cut_all", "CutReport"]
