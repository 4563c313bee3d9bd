"""`policy.toml`: what the robot needs to know to run a policy (DESIGN.md, "Policies")."""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from . import contract

FORMAT = 1


@dataclass
class TrainingRecord:
    """Where the weights came from. The hashes are datasets' content hashes
    (`dataset.json`), so `dribble score --expect train|test` can tell whether a dataset is
    the one named here."""

    dataset: str
    epochs: int
    dataset_hash: str | None = None
    # Which teacher labelled the training rows ("paper" or "observable"; DESIGN.md, "Teachers").
    teacher: str | None = None
    test_dataset_hash: str | None = None
    # (name, content hash) of every dataset trained on besides `dataset` (DAgger's rounds).
    added_datasets: list[tuple[str, str]] | None = None
    best_epoch: int | None = None
    seed: int | None = None
    validation_seeds: list[int] | None = None
    wall_time_s: float | None = None
    torch_version: str | None = None
    train_error: float | None = None
    validation_error: float | None = None
    test_error: float | None = None
    notes: str | None = None


@dataclass(frozen=True)
class ModelReference:
    """Another model a policy came from: its directory then and the first twelve digits of
    its network's sha256, which still name it after a rename."""

    model: str
    sha256: str
    how: str | None = None

    def toml(self) -> str:
        how = f", how = {_string(self.how)}" if self.how else ""
        return f"{{ model = {_string(self.model)}, sha256 = {_string(self.sha256)}{how} }}"


@dataclass
class Lineage:
    """`[lineage]`: the models a policy came from, so that its name need not say it."""

    started_from: ModelReference | None = None
    distilled_from: ModelReference | None = None
    # The CNN whose convolutions an R-CNN took (--features-from).
    features_from: ModelReference | None = None
    former_names: list[str] = field(default_factory=list)

    def to_toml(self) -> list[str]:
        lines = ["", "# Where the weights came from (an int8 policy's float one: [quantization]).", "[lineage]"]
        for key in ("started_from", "distilled_from", "features_from"):
            if getattr(self, key) is not None:
                lines.append(f"{key} = {getattr(self, key).toml()}")
        if self.former_names:
            lines.append(f"former_names = [{', '.join(_string(n) for n in self.former_names)}]")
        return lines


@dataclass
class Manifest:
    kind: str
    networks: list[str]
    training: TrainingRecord
    centroids: list[list[float]] | None = None
    lstm_units: int | None = None
    opset: int = contract.OPSET
    command_scale: dict[str, float] = field(default_factory=lambda: dict(contract.COMMAND_SCALE))
    # Each thumbnail standardised by the controller before the network (contract.network_input).
    standardise: bool = False
    # The last command sent as a third input (`[inputs] previous`; a CNN only).
    previous: bool = False
    lineage: Lineage | None = None

    def to_toml(self) -> str:
        lines = [
            "# dribble policy manifest (shared/DESIGN.md, \"Policies\").",
            f"format = {FORMAT}",
            f'kind = "{self.kind}"',
            f"opset = {self.opset}",
            f"networks = [{', '.join(_string(n) for n in self.networks)}]",
            "",
            *(
                [
                    "# The network sees each u8 thumbnail standardised on its own:",
                    f"# (pixel - mean) / max(spread, {contract.STANDARDISE_FLOOR_LEVELS:g}) in pixel levels; scale cancels.",
                    "[normalisation]",
                    f"scale = {_float(contract.INPUT_SCALE)}",
                    "standardise = true",
                ]
                if self.standardise
                else [
                    "# The network sees value * scale of each u8 thumbnail pixel.",
                    "[normalisation]",
                    f"scale = {_float(contract.INPUT_SCALE)}",
                ]
            ),
            "",
            "[inputs]",
            f'top = {{ name = "{contract.TOP_INPUT}", shape = [1, 1, {contract.TOP_SHAPE[0]}, {contract.TOP_SHAPE[1]}] }}',
            f'bottom = {{ name = "{contract.BOTTOM_INPUT}", shape = [1, 1, {contract.BOTTOM_SHAPE[0]}, {contract.BOTTOM_SHAPE[1]}] }}',
            *(
                [
                    "# The command the controller sent last: normalised, clamped, a stop where it",
                    "# sent a stop, zero at an episode's start.",
                    f'previous = {{ name = "{contract.PREVIOUS_INPUT}", shape = [1, 3] }}',
                ]
                if self.previous
                else []
            ),
            "",
            "[outputs]",
            f'command = {{ name = "{contract.COMMAND_OUTPUT}", shape = [1, 3] }}',
            "",
            "# What a normalised command of 1.0 means.",
            "[command_scale]",
            *(f"{key} = {_float(value)}" for key, value in self.command_scale.items()),
        ]
        if self.kind == "rcnn":
            units = self.lstm_units or contract.LSTM_UNITS
            lines += [
                "",
                "# LSTM state, zero at an episode's start, carried from outputs to inputs.",
                "[recurrent]",
                f"units = {units}",
                f'h_in = "{contract.H_INPUT}"',
                f'c_in = "{contract.C_INPUT}"',
                f'h_out = "{contract.H_OUTPUT}"',
                f'c_out = "{contract.C_OUTPUT}"',
            ]
        if self.kind == "hcnn":
            assert self.centroids is not None, "an H-CNN manifest needs centroids"
            rows = ",\n".join("  [" + ", ".join(_float(v) for v in row) + "]" for row in self.centroids)
            lines += [
                "",
                "# Nearest centroid (Euclidean) of the 10-value histogram feature picks networks[k].",
                "[gating]",
                f"clusters = {len(self.centroids)}",
                f"centroids = [\n{rows},\n]",
            ]
        if self.lineage is not None:
            lines += self.lineage.to_toml()
        lines += ["", "[training]", f"dataset = {_string(self.training.dataset)}", f"epochs = {self.training.epochs}"]
        t = self.training
        for key in ("dataset_hash", "teacher", "test_dataset_hash", "torch_version", "notes"):
            if getattr(t, key) is not None:
                lines.append(f"{key} = {_string(getattr(t, key))}")
        for key in ("best_epoch", "seed"):
            if getattr(t, key) is not None:
                lines.append(f"{key} = {int(getattr(t, key))}")
        if t.added_datasets:
            entries = ", ".join(f"{{ name = {_string(n)}, hash = {_string(h)} }}" for n, h in t.added_datasets)
            lines.append(f"added_datasets = [{entries}]")
        if t.validation_seeds is not None:
            lines.append(f"validation_seeds = [{', '.join(str(int(s)) for s in t.validation_seeds)}]")
        for key in ("wall_time_s", "train_error", "validation_error", "test_error"):
            value = getattr(t, key)
            if value is not None:
                lines.append(f"{key} = {_float(value)}")
        return "\n".join(lines) + "\n"

    def write(self, directory: Path) -> Path:
        path = Path(directory) / "policy.toml"
        path.write_text(self.to_toml())
        return path


def load(path: Path) -> dict:
    with open(path, "rb") as file:
        return tomllib.load(file)


def _float(value: float) -> str:
    if not math.isfinite(value):
        raise ValueError(f"manifest values must be finite, got {value}")
    return repr(float(value))


def _string(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
