"""The one rule that chooses a model (the shipped row of the results table, a DAgger
iteration): most goals in closed loop on the selection episodes, then the lowest validation
error. The selection episodes are training seeds held out from fitting (90..99) or the
selection seeds 20000..20049 (shared/DESIGN.md, "Metrics"); test seeds (10000..10019,
30000..30099) are for reporting only, and a `select.json` that holds one is refused.

The choice is made on one set of seeds: the largest any candidate was evaluated on (the
selection seeds 20000..20049 once they are run; the retired 90..99 before). A candidate
without a `select.json`, or with one on other seeds, is ranked after every candidate on the
chosen set, and the reason says so: its run must be repeated to compete. Candidates on the
same seeds but run by different engines cannot be compared (a closed loop amplifies an
engine's rounding): that is refused.
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

    def key(self, seeds: tuple[int, ...] | None = None) -> tuple:
        counted = self.selection is not None and (seeds is None or self.selection.seeds == seeds)
        goals = self.selection.goals if counted else -1
        validation = self.validation_error if self.validation_error is not None else math.inf
        return (-goals, validation, self.name)

    def reason(self, seeds: tuple[int, ...] | None = None) -> str:
        validation = "no validation error" if self.validation_error is None else f"validation error {self.validation_error:.3f}"
        if self.selection is None:
            return f"no selection run (select.json), {validation}"
        if seeds is not None and self.selection.seeds != seeds:
            return (
                f"selection run on seeds {describe(self.selection.seeds)}, not the chosen set {describe(seeds)}: "
                f"ranked last until run again, {validation}"
            )
        return f"{self.selection.goals} goals in {self.selection.episodes} selection episodes, {validation}"


def describe(seeds: tuple[int, ...]) -> str:
    return f"{seeds[0]}..{seeds[-1]} ({len(seeds)})"


def chosen_seeds(candidates: list[Candidate]) -> tuple[int, ...] | None:
    """The seed set the choice is made on: the largest any candidate was evaluated on (the
    larger set has more power); on a tie in size, the later seeds (the newer set)."""
    sets = {c.selection.seeds for c in candidates if c.selection is not None}
    return max(sets, key=lambda s: (len(s), s)) if sets else None


def choose(candidates: list[Candidate]) -> Candidate:
    """Most selection goals on the chosen seed set, then the lowest validation error, then
    the name (so a tie is decided the same way every time)."""
    if not candidates:
        raise SelectionError("nothing to choose from")
    seeds = chosen_seeds(candidates)
    engines = {c.selection.engine for c in candidates if c.selection is not None and c.selection.seeds == seeds}
    if len(engines) > 1:
        described = "; ".join(f"{c.name}: {c.selection.engine}" for c in candidates if c.selection is not None and c.selection.seeds == seeds)
        raise SelectionError(f"the candidates' selection runs on {describe(seeds)} were run by different engines, run them again with one: {described}")
    return min(candidates, key=lambda c: c.key(seeds))
