"""The episode seed ranges of DESIGN.md, and the rule that joins them: training, DAgger rounds
and calibration learn only from episodes whose seeds are outside the ranges kept for choosing
(the selection seeds) and for reporting (the test and fresh seeds).

A dataset recorded on those seeds exists for its own purpose (the test dataset scores a
model's error; selection and fresh runs are closed loops), but it never reaches a gradient or
a calibration: every consumer of training data calls `refuse_reserved` on its seeds.
"""

from __future__ import annotations

from collections.abc import Iterable

from .dataset import DatasetError

#: Demonstrations (`dribble record`'s default), the last ones held out for validation.
TRAINING = range(0, 100)
#: DAgger rounds draw their seeds here (scripts/dagger: 1000*i + offset).
DAGGER = range(1000, 10000)
#: The paper's 20 test episodes: reporting only.
TEST = range(10_000, 10_020)
#: Where checkpoints, iterations, hyperparameters and shipped models are chosen.
SELECTION = range(20_000, 20_050)
#: The 100 fresh test episodes: reporting only.
FRESH = range(30_000, 30_100)

#: Ranges no training data may come from, by name.
RESERVED = {"test": TEST, "selection": SELECTION, "fresh": FRESH}


class ReservedSeedError(DatasetError):
    """Training data that holds episodes of a reserved range."""


def reserved_among(seeds: Iterable[int]) -> dict[str, list[int]]:
    """The seeds of `seeds` that lie in a reserved range, by range name (empty: none)."""
    found: dict[str, list[int]] = {}
    for seed in sorted({int(s) for s in seeds}):
        for name, seeds_of in RESERVED.items():
            if seed in seeds_of:
                found.setdefault(name, []).append(seed)
    return found


def refuse_reserved(seeds: Iterable[int], what: str, use: str = "training") -> None:
    """Raises `ReservedSeedError` if `what` (a dataset, a round) holds reserved seeds."""
    found = reserved_among(seeds)
    if found:
        named = "; ".join(f"{name} seeds {values[:5]}{' ...' if len(values) > 5 else ''}" for name, values in found.items())
        raise ReservedSeedError(
            f"{what} holds episodes of seeds kept for choosing and reporting ({named}): they are never {use} data "
            f"(training seeds {TRAINING.start}..{TRAINING.stop - 1}, DAgger rounds {DAGGER.start}..{DAGGER.stop - 1})"
        )
