"""Recorded demonstrations as `dribble record` writes them (DESIGN.md, "Dataset").

A dataset directory holds one `.npz` per episode and `dataset.json`, which lists every
episode's SHA-256 and a content hash over them: SHA-256 of the lines `"{seed} {sha256}\\n"`
in seed order (the same rule as `dribble_sim::dataset`). Loading checks both, so a model's
manifest can name the exact data it learned from, and a missing or changed episode is an
error that says which one.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .command_metric import sent_commands

PHASES = ("search", "approach", "align", "dribble")


class DatasetError(Exception):
    """A dataset directory that cannot be used as it is."""


@dataclass
class Episode:
    seed: int
    top: np.ndarray  # u8 [T, 120, 160]
    bottom: np.ndarray  # u8 [T, 60, 80]
    command: np.ndarray  # f32 [T, 3]
    phase: np.ndarray  # u8 [T]
    # Ground truth beside the images, for analysis only (never a network input): the robot's
    # pose (x m, y m, heading rad) and the ball (x m, y m) on the field, and the simulated time.
    robot_pose: np.ndarray | None = None  # f32 [T, 3]
    ball: np.ndarray | None = None  # f32 [T, 2]
    time_s: np.ndarray | None = None  # f64 [T]
    # The conditions it was recorded under as `dribble record` names them ("clean",
    # "noise:3,robots:2"); None where dataset.json predates conditions.
    conditions: str | None = None
    # Recorded with `dribble record --clean-twin`: the thumbnails of the same frames without
    # camera effects and light (the venue and the robots kept).
    top_clean: np.ndarray | None = None  # u8 [T, 120, 160]
    bottom_clean: np.ndarray | None = None  # u8 [T, 60, 80]
    # The command the robot executed at the row before each row, as the controller sends it
    # (clamped; zero at the first row): what a network reading its last command (`[inputs]
    # previous`) is fed. From the recording (`executed_before`); None where not given, which
    # `previous` reads as the labels' own.
    executed_before: np.ndarray | None = None  # f32 [T, 3]

    def __len__(self) -> int:
        return len(self.phase)

    @property
    def previous(self) -> np.ndarray:
        """The last command before each row [T, 3] (`executed_before`, or for an episode
        without it the row before's label: what a teacher-driven recording executed)."""
        if self.executed_before is not None:
            return self.executed_before
        return executed_before(self.command)

    def rows(self, start: int, end: int) -> "Episode":
        """Rows start..end (exclusive) as an episode of the same seed."""
        part = slice(start, end)
        optional = (None if a is None else a[part] for a in (self.robot_pose, self.ball, self.time_s))
        twin = (None if a is None else a[part] for a in (self.top_clean, self.bottom_clean))
        executed = None if self.executed_before is None else self.executed_before[part]
        return Episode(self.seed, self.top[part], self.bottom[part], self.command[part], self.phase[part], *optional, self.conditions, *twin, executed)

    @property
    def has_clean_twin(self) -> bool:
        return self.top_clean is not None


@dataclass
class Dataset:
    directory: Path
    content_hash: str
    episodes: list[Episode]
    # Who labelled the rows: "paper" (the expert on ground truth; also every dataset recorded
    # before `dribble record --teacher`) or "observable" (DESIGN.md, "Teachers").
    teacher: str = "paper"

    @property
    def rows(self) -> int:
        return sum(len(e) for e in self.episodes)

    def seeds(self) -> list[int]:
        return [e.seed for e in self.episodes]

    def subset(self, seeds: list[int]) -> list[Episode]:
        wanted = set(seeds)
        return [e for e in self.episodes if e.seed in wanted]


def executed_before(executed: np.ndarray) -> np.ndarray:
    """Each row's last command: the command executed at the row before, clamped as the
    controller clamps what it sends (a non-finite one a stop), zero before the first."""
    executed = np.asarray(executed, dtype=np.float32)
    previous = np.zeros_like(executed)
    previous[1:] = sent_commands(executed[:-1])
    return previous


def executed_commands(arrays, labels: np.ndarray) -> np.ndarray:
    """What the robot executed at each row: the labels of an expert-driven episode; in a
    policy-driven one (`policy_command`, `expert_executed`) the policy's command, or the
    expert's where DAgger's draw executed it."""
    if "policy_command" not in arrays.files:
        return labels
    policy = arrays["policy_command"].astype(np.float32)
    expert = arrays["expert_executed"].astype(bool)[:, None]
    return np.where(expert, labels, policy).astype(np.float32)


def content_hash(entries: list[dict]) -> str:
    lines = "".join(f"{e['seed']} {e['sha256']}\n" for e in sorted(entries, key=lambda e: e["seed"]))
    return hashlib.sha256(lines.encode()).hexdigest()


def read_index(directory: Path) -> dict:
    directory = Path(directory)
    path = directory / "dataset.json"
    if not path.is_file():
        raise DatasetError(f"{directory} is not a dataset: it has no dataset.json (record one with `dribble record`)")
    try:
        index = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise DatasetError(f"{path} is not valid JSON: {error}") from error
    if not index.get("episodes"):
        raise DatasetError(f"{path} lists no episodes")
    return index


def verify(directory: Path, index: dict) -> str:
    """Checks every listed episode against its hash; returns the dataset's content hash."""
    directory = Path(directory)
    for entry in index["episodes"]:
        path = directory / entry["file"]
        if not path.is_file():
            raise DatasetError(f"{directory}: episode {entry['seed']} is listed in dataset.json but {entry['file']} is missing")
        expected = entry.get("sha256")
        if expected is None:
            raise DatasetError(f"{directory}: dataset.json lists no hash for episode {entry['seed']}; re-record it with `dribble record`")
        found = hashlib.sha256(path.read_bytes()).hexdigest()
        if found != expected:
            raise DatasetError(
                f"{directory}: {entry['file']} (episode {entry['seed']}) is not the file dataset.json lists: "
                f"its SHA-256 is {found}, expected {expected}; re-record it with `dribble record`"
            )
    digest = content_hash(index["episodes"])
    if index.get("content_hash") not in (None, digest):
        raise DatasetError(f"{directory}: dataset.json's content_hash {index['content_hash']} does not match its episodes ({digest})")
    return digest


def load(directory: Path, require_seeds: list[int] | None = None) -> Dataset:
    """Loads and checks a dataset; `require_seeds` must all be in it."""
    directory = Path(directory)
    index = read_index(directory)
    digest = verify(directory, index)
    if require_seeds is not None:
        present = {e["seed"] for e in index["episodes"]}
        missing = [s for s in require_seeds if s not in present]
        if missing:
            raise DatasetError(f"{directory}: the episodes {missing} were asked for but are not in this dataset")
    episodes = []
    for entry in sorted(index["episodes"], key=lambda e: e["seed"]):
        with np.load(directory / entry["file"]) as arrays:
            episode = Episode(
                seed=int(entry["seed"]),
                top=arrays["top"],
                bottom=arrays["bottom"],
                command=arrays["command"].astype(np.float32),
                phase=arrays["phase"],
                robot_pose=arrays["robot_pose"] if "robot_pose" in arrays.files else None,
                ball=arrays["ball"] if "ball" in arrays.files else None,
                time_s=arrays["time_s"] if "time_s" in arrays.files else None,
                conditions=entry.get("conditions"),
                top_clean=arrays["top_clean"] if "top_clean" in arrays.files else None,
                bottom_clean=arrays["bottom_clean"] if "bottom_clean" in arrays.files else None,
            )
            episode.executed_before = executed_before(executed_commands(arrays, episode.command))
        rows = len(episode)
        shapes = (episode.top.shape, episode.bottom.shape, episode.command.shape)
        if shapes != ((rows, 120, 160), (rows, 60, 80), (rows, 3)) or rows != entry["rows"]:
            raise DatasetError(f"{directory / entry['file']}: arrays {shapes} do not hold the {entry['rows']} rows dataset.json lists")
        if (episode.top_clean is None) != (episode.bottom_clean is None) or (
            episode.has_clean_twin and (episode.top_clean.shape, episode.bottom_clean.shape) != ((rows, 120, 160), (rows, 60, 80))
        ):
            raise DatasetError(f"{directory / entry['file']}: its clean twin's thumbnails (top_clean, bottom_clean) do not hold its {rows} rows")
        episodes.append(episode)
    return Dataset(directory, digest, episodes, teacher=index.get("teacher") or "paper")
