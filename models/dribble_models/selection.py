"""The one rule that chooses a model (the shipped row of the results table, a DAgger
iteration): most goals in closed loop on the selection episodes, then the lowest validation
error. The selection episodes are training seeds held out from fitting (90..99) or the
selection seeds 20000..20049 (shared/DESIGN.md, "Metrics"); test seeds (10000..10019,
30000..30099) are for reporting only, and a `select.json` that holds one is refused.

A candidate without a `select.json` was never evaluated for selection: it is ranked after
every candidate that was, and the reason says so. Candidates evaluated on different seeds
cannot be compared: that is refused too.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

TEST_SEEDS = frozenset(range(10000, 10020)) | frozenset(range(30000, 30100))


class SelectionError(ValueError):
    """A selection file that cannot take part in a choice."""


@dataclass(frozen=True)
class Selection:
    """What a candidate's `select.json` says: goals, episodes, and on which seeds."""

    goals: int
    episodes: int
    seeds: tuple[int, ...]
    engine: str | None


def read_selection(path: Path) -> Selection | None:
    """The selection run in `path` (an `eval_summary` JSON), or None if there is none."""
    if not path.is_file():
        return None
    summary = json.loads(path.read_text())
    episodes = summary.get("episodes") or []
    if not episodes:
        raise SelectionError(f"{path}: no episodes")
    seeds = tuple(int(e["seed"]) for e in episodes)
    tested = sorted(TEST_SEEDS.intersection(seeds))
    if tested:
        raise SelectionError(f"{path}: test seeds {tested[:5]} are for reporting only, never for choosing")
    if len(set(seeds)) != len(seeds):
        raise SelectionError(f"{path}: a seed appears twice")
    goals = sum(e["outcome"] == "goal" for e in episodes)
    return Selection(goals=goals, episodes=len(episodes), seeds=tuple(sorted(seeds)), engine=summary.get("engine"))


@dataclass(frozen=True)
class Candidate:
    """One model that may be chosen: a name, its selection run, its validation error."""

    name: str
    selection: Selection | None
    validation_error: float | None

    def key(self) -> tuple:
        goals = self.selection.goals if self.selection else -1
        validation = self.validation_error if self.validation_error is not None else math.inf
        return (-goals, validation, self.name)

    def reason(self) -> str:
        validation = "no validation error" if self.validation_error is None else f"validation error {self.validation_error:.3f}"
        if self.selection is None:
            return f"no selection run (select.json), {validation}"
        return f"{self.selection.goals} goals in {self.selection.episodes} selection episodes, {validation}"


def choose(candidates: list[Candidate]) -> Candidate:
    """Most selection goals, then the lowest validation error, then the name (so a tie is
    decided the same way every time). Every candidate that has a selection run must have it
    on the same seeds."""
    if not candidates:
        raise SelectionError("nothing to choose from")
    seed_sets = {c.selection.seeds for c in candidates if c.selection is not None}
    if len(seed_sets) > 1:
        described = "; ".join(f"{c.name}: {c.selection.seeds[0]}..{c.selection.seeds[-1]} ({c.selection.episodes})" for c in candidates if c.selection)
        raise SelectionError(f"the candidates were evaluated on different selection seeds: {described}")
    return min(candidates, key=Candidate.key)
