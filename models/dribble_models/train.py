"""Behaviour cloning of the expert: trains the paper's CNN, H-CNN or R-CNN on recorded
demonstrations and exports a model directory the controller loads.

    python -m dribble_models.train --kind cnn|hcnn|rcnn --dataset DIR --out DIR [--test-dataset DIR]

- Data: the `.npz` episodes of a `dribble record` directory, checked against `dataset.json`
  (hashes); the manifest records the content hash of the data trained and tested on.
- Validation: whole training episodes held out (a seeded choice, never test episodes); the
  epoch with the lowest validation error gives the shipped weights.
- Error: the paper's metric as the robot would produce it: the Euclidean distance between the
  command the controller sends (network output clamped to [-1, 1]; a non-finite output is a
  stop) and the expert's, averaged over rows. `dribble score` computes the same with the
  robot's code.
- CNN and H-CNN: Adam on the mean squared error over shuffled rows; an epoch visits
  `--epoch-fraction` of the training rows (consecutive 30 Hz frames are nearly the same).
  H-CNN: k-means (K = 4) on the 5-bin histograms of the training rows, one CNN per cluster,
  each trained on its cluster's rows.
- R-CNN: 100-step windows of whole episodes, in `--lanes` parallel lanes; the LSTM state is
  carried from one window to the next of the same episode and zero at an episode's start,
  as the controller carries it (truncated back-propagation through time). Evaluation steps
  every episode from a zero state.
- DAgger: `--add-dataset DIR` (repeatable) adds every episode of a policy-driven dataset
  (`dribble record --driver POLICY --label-with expert`: the expert's labels for the states
  the policy visited) to the training rows; validation stays on `--dataset`'s held-out
  episodes. `--init-from CHECKPOINT|MODEL` starts from another run's kept weights, or from a
  shipped model's (dribble_models.shipped_weights). `--prune-from MODEL` starts a narrower CNN
  (`--filters`) from a wider shipped one, each convolution keeping its filters of largest L1
  norm (`load_pruned_weights`): with `--distill-from`, a narrow network that begins near the
  wide one's function.
- Distillation (beyond the paper): `--distill-from MODEL` (a shipped one-network float CNN
  trained on the same teacher) replaces every training row's label with the command that
  model sends for the row's images (clamped as the controller clamps), so a smaller network
  (`--filters`) learns the shipped network's function rather than the teacher's commands:
  where the images do not say which way the teacher turned, the shipped network has already
  settled on one answer per image, where the teacher's labels average to none. Validation,
  the checkpoint choice and every reported error stay against the teacher's labels.
- One-way detour: `--one-way-detour` relabels the detector teacher's detour around the ball
  to go always clockwise (dribble_models.one_way_detour), on training and validation rows,
  and the model names the `detector-one-way` teacher: where the two-way detour's side cannot
  be seen, its labels disagree in states that look alike.
- Detour at the ball: `--detour-weight W` samples the teacher's detour rows with the ball
  within reach (`OneWayDetour.at_ball_rows`, from the recorded ground truth) W times as often
  as the others, and keeps the teacher's label on them through a distillation: about 1 to 3 %
  of the rows, where students walk on into the ball instead of around it (`python -m
  dribble_models.detour_rows --driven` on a DAgger round shows it) and where the distilled
  model does the same.
- Device: `--device auto` (the default) trains on a CUDA GPU where PyTorch sees one, else on
  the CPU; the manifest's notes say which. On a GPU cuDNN and cuBLAS run their deterministic
  algorithms, so a seed gives the same model again on the same GPU, but not the CPU's model
  bit for bit (other kernels, other rounding). Checkpoints and the kept weights are saved
  as CPU tensors, so a run started on one may be scored or resumed on the other.
- Resumable: a checkpoint after every epoch (`--checkpoint-dir`, under ~/.cache/dribble by
  default); running the same command again continues where it stopped. Every random choice
  is seeded (`--seed`), per epoch, so a resumed run is the run it would have been.

Its parts beside this file: `prediction` (each kind's commands as the robot runs it, and the
error), `augmentation` (`--augment`, `--camera-augment`), `distillation` (`--distill-from`'s
labels), `rcnn_windows` (the R-CNN's windows and lanes), `standardised_start` (a
`--standardise-input` start from a `pixel / 255` model) and `training_record` (the manifest's
notes and lineage).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from . import contract
from .augmentation import Augment, CameraAugment, mirrorable, mirrored
from .dataset import PHASES, Dataset, DatasetError, Episode, load, read_index
from .distillation import distilled_labels
from .export import export_policy
from .gating import fit_centroids
from .manifest import TrainingRecord
from .networks import CNN, FEATURES, HCNN, PAPER_FILTERS, RCNN, CameraFeatures, Filters, ModalCNN, PreviousCommandCNN, set_standardise, standardises
from .one_way_detour import OneWayDetour
from .prediction import episode_features, gating_features, nearest, predict, score, to_input
from .rcnn_windows import lanes_in, lanes_of, masked_loss, window_schedule, window_targets
from .seed_ranges import refuse_reserved
from .shipped_weights import ShippedWeightsError, is_shipped_model, load_pruned_weights, load_shipped_weights, shipped_initializers
from .standardised_start import fold_typical_level
from .training_record import device_name, lineage_of, notes_of, start_sha256
from .stalls import CutReport, StallRule, cut_all

#: The teachers whose rows `--one-way-detour` takes: the detector teacher's, relabelled, and the
#: one-way detector teacher's own, which it leaves as they are.
ONE_WAY_TEACHERS = ("detector", "detector-one-way")
DEFAULT_EPOCHS = {"cnn": 12, "hcnn": 12, "rcnn": 12}
CHECKPOINT_FORMAT = 1


def cnn_features(path: Path) -> nn.Module:
    """The camera features (both convolution branches) of a CNN: a checkpoint this trainer
    wrote (its kept weights) or a shipped one-network float CNN."""
    cnn = CNN()
    if is_shipped_model(path):
        try:
            load_shipped_weights(cnn, path, "cnn")
        except ShippedWeightsError as error:
            raise DatasetError(f"--features-from: {error}") from error
    elif Path(path).is_file():
        state = torch.load(path, weights_only=False, map_location="cpu")
        if state["identity"]["kind"] != "cnn" or state["identity"].get("modes", 1) != 1:
            raise DatasetError(f"--features-from {path} is not a one-output CNN's checkpoint")
        cnn.load_state_dict(state["best"]["state"] if state["best"]["state"] is not None else state["model"])
    else:
        raise DatasetError(f"--features-from {path}: no such checkpoint or model")
    return cnn.features


def winner_takes_all_loss(
    model: ModalCNN, top: torch.Tensor, bottom: torch.Tensor, target: torch.Tensor, relaxation: float = 0.05, choice_weight: float = 0.1
) -> torch.Tensor:
    """Relaxed winner-takes-all: each row's squared error is its closest hypothesis's (the
    others get `relaxation` of theirs, so that none is left untrained), plus the cross-entropy
    of the choice logits against the index of that closest hypothesis."""
    hypotheses, logits = model.forward_all(top, bottom)
    errors = ((hypotheses - target[:, None, :]) ** 2).mean(dim=2)
    best = errors.argmin(dim=1)
    winner = errors.gather(1, best[:, None]).squeeze(1)
    regression = (1.0 - relaxation) * winner.mean() + relaxation * errors.mean()
    return regression + choice_weight * nn.functional.cross_entropy(logits, best)


@dataclass
class Rows:
    """Training rows of many episodes, concatenated: u8 images, f32 commands, u8 phases."""

    top: np.ndarray
    bottom: np.ndarray
    command: np.ndarray
    phase: np.ndarray
    # The command executed at the row before each row (`Episode.previous`), f32 [N, 3].
    previous: np.ndarray
    # Whether a row's label is its mirror state's too (`augmentation.mirrorable`), bool [N].
    mirrorable: np.ndarray

    @staticmethod
    def of(episodes: list[Episode]) -> "Rows":
        return Rows(
            np.concatenate([e.top for e in episodes]),
            np.concatenate([e.bottom for e in episodes]),
            np.concatenate([e.command for e in episodes]),
            np.concatenate([e.phase for e in episodes]),
            np.concatenate([e.previous for e in episodes]),
            np.concatenate([mirrorable(e.phase) for e in episodes]),
        )


def row_batches(rows: np.ndarray, fraction: float, batch: int, rng: np.random.Generator) -> list[np.ndarray]:
    """A seeded random `fraction` of `rows` (indices), in batches."""
    count = max(1, int(round(len(rows) * fraction)))
    chosen = rng.permutation(rows)[:count]
    return [np.sort(chosen[i : i + batch]) for i in range(0, len(chosen), batch)]


class Training:
    """One model's training run: data, model, optimiser, checkpoints."""

    def __init__(self, args: TrainingConfig, dataset: Dataset, added: list[Dataset] | None = None, device: torch.device | None = None):
        self.args = args
        self.device = device or torch.device("cpu")
        self.kind = args.kind
        self.dataset = dataset
        self.added = added or []
        seeds = np.array(dataset.seeds())
        held = int(args.validation_episodes)
        if held >= len(seeds):
            raise DatasetError(f"{dataset.directory} has {len(seeds)} episodes: too few to hold out {held} for validation")
        # The last seeds are held out: episodes are already random draws from their seeds, and
        # a contiguous range is one that `dribble eval --episodes A..B` can replay in closed
        # loop to choose the shipped model without touching the test episodes.
        ordered = sorted(int(s) for s in seeds)
        self.validation_seeds = ordered[len(ordered) - held :]
        self.train_episodes = dataset.subset(ordered[: len(ordered) - held])
        self.validation_episodes = dataset.subset(self.validation_seeds)
        self.cut_reports: list[tuple[Path, CutReport]] = []
        for extra in self.added:
            shared = sorted(set(extra.seeds()) & set(self.validation_seeds))
            if shared:
                raise DatasetError(f"{extra.directory} holds the validation episodes {shared} of {dataset.directory}: they would be trained on")
            episodes = extra.episodes
            if args.cut_stalls is not None:
                episodes, report = cut_all(episodes, StallRule(after_s=args.cut_stalls))
                self.cut_reports.append((extra.directory, report))
                print(f"  {extra.directory.name}: {report.describe()}", file=sys.stderr)
            self.train_episodes = self.train_episodes + episodes
        torch.manual_seed(args.seed)
        self.augment = Augment() if args.augment else None
        self.camera_augment = CameraAugment.of_strength(args.camera_augment, args.camera_augment_strength) if args.camera_augment > 0 else None
        detour = np.zeros(0, bool)
        if args.one_way_detour:
            # The teacher's two-way detour rows relabelled one way, validation's too; the
            # relabelled rows keep their label through a distillation below.
            self.train_episodes, detour = OneWayDetour().relabelled(self.train_episodes)
            self.validation_episodes, _ = OneWayDetour().relabelled(self.validation_episodes)
            print(f"one-way detour: {int(detour.sum())} of {len(detour)} training rows relabelled", file=sys.stderr)
        self.rows = Rows.of(self.train_episodes) if self.kind != "rcnn" else None
        self.at_ball = np.zeros(0, bool)
        if args.detour_weight != 1.0:
            self.at_ball = OneWayDetour().at_ball_rows(self.train_episodes)
            print(f"detour at the ball: {int(self.at_ball.sum())} of {len(self.at_ball)} training rows, sampled {args.detour_weight:g} times as often", file=sys.stderr)
        if args.distill_from is not None:
            if self.kind != "cnn":
                raise DatasetError("--distill-from trains a CNN (--kind cnn)")
            distilled = np.concatenate(distilled_labels(args, self.train_episodes, self.device))
            if args.one_way_detour:
                distilled = np.where(detour[:, None], self.rows.command, distilled)
            if len(self.at_ball):
                distilled = np.where(self.at_ball[:, None], self.rows.command, distilled)
            self.rows.command = distilled
            if args.validate_distilled:
                # Checkpoints chosen by how near the student comes to the distilled model,
                # on the held-out episodes, by the same rule as the training rows.
                labels = distilled_labels(args, self.validation_episodes, self.device)
                self.validation_episodes = [dataclasses.replace(e, command=l) for e, l in zip(self.validation_episodes, labels)]
        if self.kind == "cnn" and args.previous_command:
            self.model = PreviousCommandCNN(CameraFeatures(args.filters))
        elif self.kind == "cnn":
            self.model = CNN(args.filters) if args.modes == 1 else ModalCNN(args.modes, args.filters)
        elif self.kind == "rcnn":
            self.model = RCNN()
        else:
            features = gating_features(self.rows.top, self.rows.bottom)
            sample = np.random.default_rng([args.seed, 2]).permutation(len(features))[: args.kmeans_rows]
            centroids = fit_centroids(features[sample], args.clusters, seed=args.seed)
            self.model = HCNN(centroids)
            self.clusters = nearest(features, self.model.centroids)
        self.folded_start = False
        self.widened_start = False
        if args.init_from is not None:
            self.start_from(args.init_from)
            if args.standardise_input and not standardises(self.model) and self.rows is not None:
                self.folded_start = True
                # The start saw `pixel / 255`: its first layers re-expressed for standardised
                # input at the training rows' typical level and spread.
                fold_typical_level(self.model, self.rows, np.random.default_rng([args.seed, 3]))
        # After the start: the run's choice, whatever the model it started from did.
        set_standardise(self.model, args.standardise_input)
        if args.keep_branches:
            # The start's camera branches as they are (a folded start's re-expression
            # included): only the dense layers are given to the optimizer.
            self.model.features.requires_grad_(False)
        if args.prune_from is not None:
            if self.kind != "cnn" or args.modes != 1:
                raise DatasetError("--prune-from starts a one-output CNN (--kind cnn, --modes 1)")
            try:
                kept = load_pruned_weights(self.model, args.prune_from)
            except ShippedWeightsError as error:
                raise DatasetError(f"--prune-from: {error}") from error
            print(f"pruned from {args.prune_from}: filters kept {kept}", file=sys.stderr)
        self.model.to(self.device)
        self.feature_cache: list[torch.Tensor] | None = None
        if args.features_from is not None:
            self.model.features.load_state_dict(cnn_features(args.features_from).state_dict())
            if args.freeze_features:
                # The convolutions stay the CNN's: each episode's features are computed once.
                self.model.features.requires_grad_(False)
                self.feature_cache = [episode_features(self.model, e) for e in self.train_episodes]
        self.optimizer = torch.optim.Adam([p for p in self.model.parameters() if p.requires_grad], lr=args.lr)
        self.epoch = 0
        self.history: list[dict] = []
        self.best = {"error": math.inf, "epoch": 0, "state": None}
        self.wall_s = 0.0

    def start_from(self, path: Path) -> None:
        """Takes the kept (best) weights of another run's checkpoint, or a shipped model's, as the start.

        A CNN with command hypotheses may start from a one-output CNN: its head is widened
        (`ModalCNN.widened`), so the run begins with the start's commands."""
        if isinstance(self.model, PreviousCommandCNN):
            if self.starts_one_output(path) and not self.starts_reading_previous(path):
                # The start's function: its branches and head, the last command's weights zero.
                one = CNN(self.args.filters)
                self.load_start(one, path, modes=1)
                self.model = PreviousCommandCNN.from_cnn(one)
                return
        if isinstance(self.model, ModalCNN) and self.starts_one_output(path):
            one = CNN(self.args.filters)
            self.load_start(one, path, modes=1)
            self.model = ModalCNN.widened(one, self.args.modes)
            self.widened_start = True
            return
        self.load_start(self.model, path, modes=self.args.modes)

    def starts_one_output(self, path: Path) -> bool:
        """Whether the start at `path` is a one-output CNN (a shipped model or a checkpoint)."""
        if is_shipped_model(path):
            try:
                _, initializers = shipped_initializers(path, self.kind)
            except ShippedWeightsError as error:
                raise DatasetError(f"--init-from: {error}") from error
            return "head.2.weight" in initializers
        if not Path(path).is_file():
            raise DatasetError(f"--init-from {path}: no such checkpoint")
        identity = torch.load(path, weights_only=False, map_location="cpu")["identity"]
        return identity["kind"] == "cnn" and identity.get("modes", 1) == 1

    def starts_reading_previous(self, path: Path) -> bool:
        """Whether the start at `path` is a checkpoint of a network that reads its last command."""
        if is_shipped_model(path) or not Path(path).is_file():
            return False
        identity = torch.load(path, weights_only=False, map_location="cpu")["identity"]
        return "previous_command" in identity

    def load_start(self, model: nn.Module, path: Path, modes: int) -> None:
        """Loads the start at `path` into `model` (of `modes` hypotheses), or refuses it."""
        if is_shipped_model(path):
            try:
                load_shipped_weights(model, path, self.kind)
            except ShippedWeightsError as error:
                raise DatasetError(f"--init-from: {error}") from error
            return
        if not Path(path).is_file():
            raise DatasetError(f"--init-from {path}: no such checkpoint")
        state = torch.load(path, weights_only=False, map_location="cpu")
        if ("previous_command" in state["identity"]) != isinstance(model, PreviousCommandCNN):
            raise DatasetError(f"--init-from {path}: one of the start and this run reads its last command and the other does not")
        if state["identity"]["kind"] != self.kind or state["identity"].get("modes", 1) != modes:
            raise DatasetError(
                f"--init-from {path} is a {state['identity']['kind']} with {state['identity'].get('modes', 1)} command "
                f"hypotheses; this run trains a {self.kind} with {modes}"
            )
        filters = state["identity"].get("filters", PAPER_FILTERS.text())
        if filters != self.args.filters.text():
            raise DatasetError(f"--init-from {path} has the filters {filters}; this run trains {self.args.filters.text()}")
        if state["centroids"] is not None:
            # The H-CNN keeps the gate it was trained with.
            model = self.model = HCNN(state["centroids"])
            self.clusters = nearest(gating_features(self.rows.top, self.rows.bottom), self.model.centroids)
        model.load_state_dict(state["best"]["state"] if state["best"]["state"] is not None else state["model"])

    # -- checkpoints ---------------------------------------------------------------------

    def identity(self) -> dict:
        a = self.args
        return {
            "format": CHECKPOINT_FORMAT,
            "kind": a.kind,
            "dataset_hash": self.dataset.content_hash,
            "seed": a.seed,
            "lr": a.lr,
            "batch_size": a.batch_size,
            "epoch_fraction": a.epoch_fraction,
            "validation_episodes": a.validation_episodes,
            "augment": a.augment,
            "balance_phases": a.balance_phases,
            **({"detour_weight": a.detour_weight} if a.detour_weight != 1.0 else {}),
            "window": a.window,
            "lanes": a.lanes,
            "clusters": a.clusters,
            # Only where it differs from the paper's one output, so that older checkpoints resume.
            **({"modes": a.modes} if a.modes != 1 else {}),
            **({"camera_augment": a.camera_augment} if a.camera_augment > 0 else {}),
            **({"camera_augment_strength": a.camera_augment_strength} if a.camera_augment_strength != "standard" else {}),
            **({"standardise_input": "folded start" if self.folded_start else True} if a.standardise_input else {}),
            **({"filters": a.filters.text()} if a.filters != PAPER_FILTERS else {}),
            **({"added_datasets": [d.content_hash for d in self.added]} if self.added else {}),
            **({"init_from": start_sha256(a.init_from)} if a.init_from is not None else {}),
            **({"prune_from": start_sha256(a.prune_from)} if a.prune_from is not None else {}),
            **({"distill_from": start_sha256(a.distill_from)} if a.distill_from is not None else {}),
            **({"distill_camera_clean": True} if a.distill_camera_clean else {}),
            **({"validate_distilled": True} if a.validate_distilled else {}),
            **({"one_way_detour": True} if a.one_way_detour else {}),
            **({"previous_command": self.previous_command_record()} if a.previous_command else {}),
            **({"features_from": start_sha256(a.features_from), "freeze_features": a.freeze_features} if a.features_from is not None else {}),
            **({"keep_branches": True} if a.keep_branches else {}),
            **({"mirror": a.mirror} if a.mirror > 0 else {}),
        }

    def previous_command_record(self) -> dict:
        """How the last command is shaped on training rows, for the checkpoint's identity: each
        key only where it is set, so that checkpoints written before it existed still resume."""
        a = self.args
        record: dict = {"noise": a.previous_noise}
        if a.previous_dropout > 0:
            record["dropout"] = a.previous_dropout
            if a.previous_dropout_phases != PHASES:
                record["dropout_phases"] = list(a.previous_dropout_phases)
        if a.previous_shrink > 0:
            record["shrink"] = a.previous_shrink
        return record

    def save(self, path: Path) -> None:
        state = {
            "identity": self.identity(),
            "epoch": self.epoch,
            "model": on_cpu(self.model.state_dict()),
            "optimizer": on_cpu(self.optimizer.state_dict()),
            "history": self.history,
            "best": self.best,
            "wall_s": self.wall_s,
            "centroids": getattr(self.model, "centroids", None),
        }
        temporary = path.with_suffix(".partial")
        torch.save(state, temporary)
        os.replace(temporary, path)

    def resume(self, path: Path) -> bool:
        if not path.is_file():
            return False
        state = torch.load(path, weights_only=False, map_location="cpu")
        if state["identity"] != self.identity():
            different = {k: (state["identity"].get(k), v) for k, v in self.identity().items() if state["identity"].get(k) != v}
            raise DatasetError(
                f"the checkpoint {path} belongs to another run ({different}: checkpoint vs now); "
                "pass --fresh to start over or --checkpoint-dir to keep both"
            )
        if state["centroids"] is not None:
            self.model = HCNN(state["centroids"]).to(self.device)
            self.optimizer = torch.optim.Adam(self.model.parameters(), lr=self.args.lr)
            self.clusters = nearest(gating_features(self.rows.top, self.rows.bottom), self.model.centroids)
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.epoch, self.history, self.best, self.wall_s = state["epoch"], state["history"], state["best"], state["wall_s"]
        return True

    # -- one epoch -----------------------------------------------------------------------

    def batch_inputs(self, index: np.ndarray, generator: torch.Generator):
        top, bottom = to_input(self.rows.top[index]), to_input(self.rows.bottom[index])
        if self.augment:
            top, bottom = self.augment(top, bottom, generator)
        if self.camera_augment:
            top, bottom = self.camera_augment(top, bottom, generator)
        return top.to(self.device), bottom.to(self.device), torch.from_numpy(self.rows.command[index]).to(self.device)

    def batch_previous(self, index: np.ndarray, generator: torch.Generator) -> torch.Tensor:
        """The rows' last commands, perturbed by `--previous-noise` (Gaussian, normalised
        units): the network must not read its label off the last command to the last digit
        (imitation's copycat), and learns from its images what the last command leaves open."""
        previous = torch.from_numpy(self.rows.previous[index])
        if self.args.previous_shrink > 0:
            # A last command faded toward a stop on a share of the rows, its direction kept:
            # a network that answers a fraction of whatever it sent last (the copycat) stops
            # itself tick by tick, its answer shrinking to a stop it then keeps. Paired with the
            # teacher's full command, a faded one must be answered from the images; unlike a
            # stop in its place, it still says which way around the ball the robot was going.
            shrunk = torch.rand(len(previous), 1, generator=generator) < self.args.previous_shrink
            factor = torch.rand(len(previous), 1, generator=generator)
            previous = torch.where(shrunk, previous * factor, previous)
        if self.args.previous_noise > 0:
            previous = previous + self.args.previous_noise * torch.randn(previous.shape, generator=generator)
        if self.args.previous_dropout > 0:
            # A stop in place of the last command on a share of the rows: where the robot
            # stands (an episode's start, after a stop) its images must say what to do, or a
            # network that copies its last command never starts walking.
            # Only in the teacher's phases named (--previous-dropout-phases, all by default):
            # elsewhere the last command keeps what the images cannot show (which way around the ball).
            dropped = torch.rand(len(previous), 1, generator=generator) < self.args.previous_dropout
            named = [PHASES.index(p) for p in self.args.previous_dropout_phases]
            dropped &= torch.from_numpy(np.isin(self.rows.phase[index], named)).unsqueeze(1)
            previous = torch.where(dropped, torch.zeros_like(previous), previous)
        return previous.to(self.device)

    def epoch_rows(self, rng: np.random.Generator) -> list[tuple[int, np.ndarray]]:
        """(network, row batch) pairs of one epoch, shuffled; network 0 for a CNN."""
        every = np.arange(len(self.rows.phase))
        if self.args.balance_phases or len(self.at_ball):
            # Sampled with replacement: each phase as often as the most frequent one
            # (--balance-phases), the detour's rows at the ball --detour-weight times as often.
            weights = np.ones(len(every))
            if self.args.balance_phases:
                counts = np.bincount(self.rows.phase, minlength=4)
                weights = np.where(counts[self.rows.phase] > 0, 1.0 / counts[self.rows.phase], 0.0)
            if len(self.at_ball):
                weights = np.where(self.at_ball, weights * self.args.detour_weight, weights)
            count = len(every)
            every = rng.choice(every, size=count, p=weights / weights.sum())
        if self.kind == "cnn":
            return [(0, b) for b in row_batches(every, self.args.epoch_fraction, self.args.batch_size, rng)]
        pairs = []
        for k in range(len(self.model.experts)):
            mine = every[self.clusters[every] == k]
            if len(mine):
                pairs += [(k, b) for b in row_batches(mine, self.args.epoch_fraction, self.args.batch_size, rng)]
        order = rng.permutation(len(pairs))
        return [pairs[i] for i in order]

    def train_rows_epoch(self, rng, generator, bar) -> float:
        losses = []
        work = self.epoch_rows(rng)
        bar.reset(total=len(work))
        self.model.train()
        for k, index in work:
            network = self.model if self.kind == "cnn" else self.model.experts[k]
            top, bottom, target = self.batch_inputs(index, generator)
            previous = self.batch_previous(index, generator) if isinstance(network, PreviousCommandCNN) else None
            if self.args.mirror > 0:
                allowed = torch.from_numpy(self.rows.mirrorable[index])
                top, bottom, target, previous = mirrored(self.args.mirror, generator, allowed, top, bottom, target, previous)
            if previous is not None:
                loss = nn.functional.mse_loss(network(top, bottom, previous), target)
            elif isinstance(network, ModalCNN):
                loss = winner_takes_all_loss(network, top, bottom, target)
            else:
                loss = nn.functional.mse_loss(network(top, bottom), target)
            losses.append(self.optimise(loss))
            bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}", refresh=False)
            bar.update(1)
        return float(np.mean(losses))

    def train_rcnn_epoch(self, rng, generator, bar) -> float:
        episodes = self.train_episodes
        count = max(1, int(round(len(episodes) * self.args.epoch_fraction)))
        order = rng.permutation(len(episodes))[:count]
        schedule = window_schedule(episodes, lanes_of(episodes, order, self.args.lanes), self.args.window)
        bar.reset(total=len(schedule))
        model, window, lanes = self.model, self.args.window, self.args.lanes
        model.train()
        h, c = model.zero_state(lanes)
        losses = []
        if self.feature_cache is not None:
            model.features.eval()  # frozen: no batch statistics or dropout to update anyway
        for step in schedule:
            if self.feature_cache is not None:
                losses.append(self.train_rcnn_window_on_features(step, h, c))
                h, c = self.cached_state
                bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}", refresh=False)
                bar.update(1)
                continue
            top = torch.zeros(lanes, window, 1, *contract.TOP_SHAPE)
            bottom = torch.zeros(lanes, window, 1, *contract.BOTTOM_SHAPE)
            target, mask, fresh = window_targets(step, episodes, window, lanes, self.device)
            for lane, (e, start) in lanes_in(step):
                episode = episodes[e]
                end = min(start + window, len(episode))
                t, b = to_input(episode.top[start:end]), to_input(episode.bottom[start:end])
                if self.augment:
                    t, b = self.augment(t, b, generator)
                if self.camera_augment:
                    t, b = self.camera_augment(t, b, generator)
                top[lane, : end - start], bottom[lane, : end - start] = t, b
            top, bottom = top.to(self.device), bottom.to(self.device)
            out, (h, c) = model(top, bottom, (h * fresh, c * fresh))
            h, c = h.detach(), c.detach()
            loss = masked_loss(out, target, mask)
            losses.append(self.optimise(loss))
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}", refresh=False)
            bar.update(1)
        return float(np.mean(losses)) if losses else math.nan

    def train_rcnn_window_on_features(self, step, h, c) -> float:
        """One optimiser step of the LSTM and head on the cached features of `step`'s windows."""
        model, window, lanes = self.model, self.args.window, self.args.lanes
        features = torch.zeros(lanes, window, FEATURES)
        target, mask, fresh = window_targets(step, self.train_episodes, window, lanes, self.device)
        for lane, (e, start) in lanes_in(step):
            end = min(start + window, len(self.train_episodes[e]))
            features[lane, : end - start] = self.feature_cache[e][start:end]
        features = features.to(self.device)
        out, (h, c) = model.lstm(features, (h * fresh, c * fresh))
        self.cached_state = (h.detach(), c.detach())
        return self.optimise(masked_loss(model.head(out), target, mask))

    def optimise(self, loss: torch.Tensor) -> float:
        """One optimiser step on `loss`; its value."""
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return loss.item()

    def run(self, checkpoint: Path) -> None:
        epochs = self.args.epochs
        if self.resume(checkpoint):
            print(f"resuming from {checkpoint}: {self.epoch} of {epochs} epochs done", file=sys.stderr)
        interval = 0.5 if sys.stderr.isatty() else 30.0
        outer = tqdm(total=epochs, initial=self.epoch, desc=f"{self.kind} epochs", unit="epoch", dynamic_ncols=True, mininterval=interval)
        bar = tqdm(total=1, desc="  batches", leave=False, dynamic_ncols=True, mininterval=interval)
        while self.epoch < epochs:
            started = time.monotonic()
            rng = np.random.default_rng([self.args.seed, 100 + self.epoch])
            generator = torch.Generator().manual_seed(self.args.seed * 1000 + self.epoch)
            if self.kind == "rcnn":
                loss = self.train_rcnn_epoch(rng, generator, bar)
            else:
                loss = self.train_rows_epoch(rng, generator, bar)
            validation = score(predict(self.model, self.kind, self.validation_episodes), self.validation_episodes)
            self.epoch += 1
            self.wall_s += time.monotonic() - started
            self.history.append({"epoch": self.epoch, "loss": loss, "validation_error": validation["error"], "wall_s": self.wall_s})
            if validation["error"] < self.best["error"]:
                self.best = {"error": validation["error"], "epoch": self.epoch, "state": on_cpu(self.model.state_dict())}
            self.save(checkpoint)
            outer.set_postfix(loss=f"{loss:.4f}", val_error=f"{validation['error']:.4f}", best=f"{self.best['error']:.4f}@{self.best['epoch']}")
            outer.update(1)
        bar.close()
        outer.close()
        if self.best["state"] is not None:
            self.model.load_state_dict(self.best["state"])


def on_cpu(state):
    """A copy of a state dict (nested dicts and lists of tensors) with every tensor on the CPU,
    so that checkpoints and kept weights load anywhere."""
    if isinstance(state, torch.Tensor):
        return state.detach().to("cpu", copy=True)
    if isinstance(state, dict):
        return {k: on_cpu(v) for k, v in state.items()}
    if isinstance(state, list):
        return [on_cpu(v) for v in state]
    return state


def training_device(choice: str) -> torch.device:
    """`--device`: auto is a CUDA GPU where PyTorch sees one, else the CPU. On a GPU, cuDNN and
    cuBLAS are held to deterministic algorithms (a seed gives the same model again there) and
    to full fp32 arithmetic."""
    if choice == "auto":
        choice = "cuda" if torch.cuda.is_available() else "cpu"
    if choice == "cuda":
        if not torch.cuda.is_available():
            raise DatasetError("--device cuda: PyTorch sees no CUDA GPU here (use --device cpu or auto)")
        # Read when cuBLAS starts: its deterministic workspace.
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        torch.backends.cudnn.deterministic = True
        torch.backends.cudnn.benchmark = False
        # Full fp32 products, as the robot computes (TF32 would round inputs to 10 bits).
        torch.backends.cudnn.allow_tf32 = False
        torch.backends.cuda.matmul.allow_tf32 = False
        torch.use_deterministic_algorithms(True, warn_only=True)
    return torch.device(choice)


def plot_history(history: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [h["epoch"] for h in history]
    figure, loss_axis = plt.subplots(figsize=(7, 4), dpi=110)
    loss_axis.plot(epochs, [h["loss"] for h in history], "o-", color="tab:blue", label="training loss (MSE)")
    loss_axis.set_xlabel("epoch")
    loss_axis.set_ylabel("training loss (MSE)", color="tab:blue")
    error_axis = loss_axis.twinx()
    error_axis.plot(epochs, [h["validation_error"] for h in history], "s-", color="tab:red", label="validation error")
    best = min(history, key=lambda h: h["validation_error"])
    error_axis.axvline(best["epoch"], color="tab:gray", linestyle=":", label=f"kept: epoch {best['epoch']}")
    error_axis.set_ylabel("validation error (paper metric)", color="tab:red")
    figure.legend(loc="upper right", fontsize=8)
    loss_axis.set_title(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


@dataclass(frozen=True)
class TrainingConfig:
    """Everything one training run is told (`python -m dribble_models.train --help` says what
    each means); made by `parse_args`, which checks that the options fit together."""

    kind: str
    dataset: Path
    out: Path
    add_dataset: tuple[Path, ...] = ()
    cut_stalls: float | None = None
    init_from: Path | None = None
    prune_from: Path | None = None
    distill_from: Path | None = None
    distill_camera_clean: bool = False
    validate_distilled: bool = False
    one_way_detour: bool = False
    previous_command: bool = False
    previous_noise: float = 0.2
    previous_dropout: float = 0.0
    previous_dropout_phases: tuple[str, ...] = PHASES
    previous_shrink: float = 0.0
    keep_branches: bool = False
    mirror: float = 0.0
    test_dataset: Path | None = None
    epochs: int = 0
    epoch_fraction: float = 1.0
    batch_size: int = 64
    lr: float = 1e-3
    seed: int = 0
    validation_episodes: int = 10
    window: int = 100
    features_from: Path | None = None
    freeze_features: bool = False
    lanes: int = 4
    clusters: int = contract.DEFAULT_CLUSTERS
    kmeans_rows: int = 20000
    filters: Filters = PAPER_FILTERS
    modes: int = 1
    augment: bool = False
    camera_augment: float = 0.0
    camera_augment_strength: str = "standard"
    standardise_input: bool = False
    balance_phases: bool = False
    detour_weight: float = 1.0
    threads: int = 1
    device: str = "auto"
    checkpoint_dir: Path | None = None
    fresh: bool = False

    @classmethod
    def from_namespace(cls, namespace: argparse.Namespace) -> "TrainingConfig":
        """The configuration `parse_args`' parser read (every field named as its option)."""
        values = vars(namespace)
        return cls(**{f.name: values[f.name] for f in fields(cls)} | {"add_dataset": tuple(values["add_dataset"])})


def phase_list(text: str) -> tuple[str, ...]:
    """A comma list of the teacher's phases (dataset.PHASES), kept in their order."""
    named = {p.strip() for p in text.split(",") if p.strip()}
    unknown = named - set(PHASES)
    if not named or unknown:
        raise argparse.ArgumentTypeError(f"phases are a comma list of {', '.join(PHASES)} (got {text!r})")
    return tuple(p for p in PHASES if p in named)


def parse_args(argv: list[str] | None = None) -> TrainingConfig:
    parser = argparse.ArgumentParser(
        prog="python -m dribble_models.train",
        description="Train a policy (behaviour cloning of the expert) and export it for the controller.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--kind", choices=contract.KINDS, required=True, help="network: the paper's CNN, H-CNN or R-CNN")
    parser.add_argument("--dataset", type=Path, required=True, help="training data: a `dribble record` directory")
    parser.add_argument("--out", type=Path, required=True, help="model directory to write (policy.toml, ONNX, loss curve, scores)")
    parser.add_argument("--add-dataset", type=Path, action="append", default=[], help="more training data, every episode of it (DAgger's policy-driven, expert-labelled rounds); repeatable")
    parser.add_argument("--cut-stalls", type=float, metavar="SECONDS", help="in the --add-dataset rounds, drop the rows of a stall (robot and ball still) after its first SECONDS (dribble_models.stalls explains why)")
    parser.add_argument("--init-from", type=Path, help="start from the kept weights of this checkpoint (a .pt this trainer wrote), or from a shipped one-network float model (its directory or policy.toml: dribble_models.shipped_weights), instead of random ones")
    parser.add_argument("--prune-from", type=Path, metavar="MODEL", help="CNN: start from this wider shipped one-network float CNN, each convolution keeping its --filters filters of largest L1 norm (and the next layers the matching channels and columns) instead of random weights")
    parser.add_argument("--distill-from", type=Path, metavar="MODEL", help="CNN: train on the commands this shipped one-network float CNN sends for each training row's images instead of the teacher's labels (knowledge distillation into a smaller --filters network; validation on the teacher's labels unless --validate-distilled)")
    parser.add_argument("--distill-camera-clean", action="store_true", help="with --distill-from: its commands only where a model trained on clean renders sees as it learned to: the rows of episodes recorded with no camera, light or venue condition (clean, robots), and conditioned rows recorded with a clean twin (`dribble record --clean-twin`: its commands on the twin's thumbnails); the teacher's labels on the rest (a robust student of a clean-trained policy, with --camera-augment)")
    parser.add_argument("--validate-distilled", action="store_true", help="with --distill-from: the held-out episodes take the distilled labels too (by the same rule as the training rows), so the kept checkpoint is the one nearest the distilled model rather than the teacher")
    parser.add_argument("--one-way-detour", action="store_true", help="where the teacher walks around the ball to get behind it, on the side of the ball-to-goal line it stands on (a side the images often cannot show), label the rows with the same walk around the ball always clockwise; training and validation rows (dribble_models.one_way_detour)")
    parser.add_argument("--previous-command", action="store_true", help="CNN: the network also reads the command the controller sent last (a third input, [inputs] previous: beyond the paper), fed on each row the command the recording executed at the row before; a one-output CNN start begins as its own function, the new weights zero (PreviousCommandCNN)")
    parser.add_argument("--previous-noise", type=float, default=0.2, metavar="SIGMA", help="with --previous-command: Gaussian noise on the last command of training rows, in normalised units (default 0.2)")
    parser.add_argument("--previous-dropout", type=float, default=0.0, metavar="SHARE", help="with --previous-command: this share of training rows is given a stop as the last command, so that a standing robot's images say what to do (against the copycat that never starts; default 0)")
    parser.add_argument(
        "--previous-dropout-phases",
        type=phase_list,
        default=PHASES,
        metavar="P,Q",
        help="with --previous-dropout: only rows in these teacher's phases (a comma list of " + ", ".join(PHASES) + ") are given the stop; default all",
    )
    parser.add_argument(
        "--previous-shrink",
        type=float,
        default=0.0,
        metavar="SHARE",
        help="with --previous-command: on this share of training rows the last command is scaled by a factor drawn uniformly in [0, 1), "
        "its direction kept (a command fading toward a stop), the label the teacher's: against the copycat that answers a fraction "
        "of its last command and so comes to a stop it keeps (default 0)",
    )
    parser.add_argument(
        "--mirror",
        type=float,
        default=0.0,
        metavar="SHARE",
        help="CNN: on this share of the training rows both thumbnails are mirrored left to right and the command's sideways "
        "and turn axes negated (the last command's too, with --previous-command): the field, its goals, the walk and the "
        "teacher are the same seen in a mirror along the field's long axis, so each row is also the row of its mirror "
        "state (beyond the paper; default 0)",
    )
    parser.add_argument("--keep-branches", action="store_true", help="CNN with --init-from: the start's camera branches stay as they are and only the dense layers learn (with --previous-command, the new input's weights too), so the network keeps reading its images as the start did; augmentation still reaches the branches' input")
    parser.add_argument("--test-dataset", type=Path, help="test data for the test error in the manifest (reported, never used to choose)")
    parser.add_argument("--epochs", type=int, help=f"epochs (default {DEFAULT_EPOCHS})")
    parser.add_argument("--epoch-fraction", type=float, default=1.0, help="share of training rows (R-CNN: episodes) one epoch visits")
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random choice")
    parser.add_argument("--validation-episodes", type=int, default=10, help="the last N training episodes (by seed) are held out to choose the checkpoint and the shipped model")
    parser.add_argument("--window", type=int, default=100, help="R-CNN: steps per training window")
    parser.add_argument("--features-from", type=Path, help="R-CNN: start the convolutions from this CNN (a checkpoint this trainer wrote, or a shipped one-network float CNN's directory)")
    parser.add_argument("--freeze-features", action="store_true", help="R-CNN with --features-from: keep those convolutions fixed and train the LSTM and head only (features computed once per episode, so windows can hold a whole search)")
    parser.add_argument("--lanes", type=int, default=4, help="R-CNN: episodes trained side by side")
    parser.add_argument("--clusters", type=int, default=contract.DEFAULT_CLUSTERS, help="H-CNN: K")
    parser.add_argument("--kmeans-rows", type=int, default=20000, help="H-CNN: rows sampled for k-means")
    parser.add_argument("--filters", type=Filters.parse, default=PAPER_FILTERS, help="CNN: the four convolutions' filter counts, top first, top second, bottom first, bottom second (beyond the paper; default its 16,32,8,16; fewer for the Nao V5's tick)")
    parser.add_argument("--modes", type=int, default=1, help="CNN: command hypotheses with a learned choice among them (beyond the paper; 1 is the paper's CNN)")
    parser.add_argument("--augment", action="store_true", help="jitter brightness, add noise, shift images (beyond the paper)")
    parser.add_argument("--camera-augment", type=float, default=0.0, metavar="SHARE", help="apply what the simulator's camera conditions do (exposure, contrast, vignetting, blur, noise) to this share of the training rows (0: none; CameraAugment)")
    parser.add_argument("--camera-augment-strength", choices=CameraAugment.STRENGTHS, default="standard", help="the ranges of --camera-augment: standard (up to 1.2 EV, contrast 0.4, noise 0.04) strong (up to 1.6 EV, contrast 0.25, noise 0.06, past the simulator's severity 5, each effect on 70%% of the augmented rows), or motion-and-light (the standard ranges, the camera's turn as a directional smear of up to 8 and a rolling-shutter skew of up to 6 thumbnail pixels on 40%% of the augmented rows, and soft shadows and bright spots)")
    parser.add_argument("--standardise-input", action="store_true", help="the controller standardises each thumbnail on its own before the network (mean 0, spread 1, at least 4 levels: [normalisation] standardise in policy.toml), so exposure, gain and contrast change nothing the network sees (beyond the paper)")
    parser.add_argument("--balance-phases", action="store_true", help="sample each expert phase equally often (beyond the paper)")
    parser.add_argument(
        "--detour-weight",
        type=float,
        default=1.0,
        metavar="W",
        help="sample the teacher's detour rows with the ball within reach W times as often, with the teacher's labels through a distillation (CNN; beyond the paper; 1: as any row)",
    )
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="PyTorch CPU threads")
    parser.add_argument(
        "--device",
        choices=("auto", "cpu", "cuda"),
        default="auto",
        help="where to train: auto is a CUDA GPU where PyTorch sees one, else the CPU (a GPU's model is not the CPU's bit for bit; the manifest's notes name the GPU)",
    )
    parser.add_argument("--checkpoint-dir", type=Path, help="where the resumable checkpoint lives (default ~/.cache/dribble/checkpoints/<out>)")
    parser.add_argument("--fresh", action="store_true", help="ignore an existing checkpoint and start over")
    args = parser.parse_args(argv)
    if args.epochs is None:
        args.epochs = DEFAULT_EPOCHS[args.kind]
    if not 0.0 < args.epoch_fraction <= 1.0:
        parser.error("--epoch-fraction must be in (0, 1]")
    if args.distill_camera_clean and args.distill_from is None:
        parser.error("--distill-camera-clean says where --distill-from's commands are taken: give --distill-from")
    if args.validate_distilled and args.distill_from is None:
        parser.error("--validate-distilled validates on --distill-from's commands: give --distill-from")
    if args.cut_stalls is not None and not args.cut_stalls > 0:
        parser.error("--cut-stalls is a positive number of seconds")
    if args.modes < 1 or (args.modes > 1 and args.kind != "cnn"):
        parser.error("--modes is 1, or more for --kind cnn only")
    if args.filters != PAPER_FILTERS and args.kind != "cnn":
        parser.error("--filters other than the paper's are for --kind cnn only")
    if args.features_from is not None and args.kind != "rcnn":
        parser.error("--features-from starts an R-CNN's convolutions (--kind rcnn)")
    if args.freeze_features and args.features_from is None:
        parser.error("--freeze-features needs --features-from")
    if not 0.0 <= args.camera_augment <= 1.0:
        parser.error("--camera-augment is a share of the rows, in [0, 1]")
    if args.freeze_features and (args.augment or args.camera_augment > 0):
        parser.error("--freeze-features computes each episode's features once: no --augment")
    if args.previous_command and (args.kind != "cnn" or args.modes != 1 or args.prune_from is not None):
        parser.error("--previous-command trains a one-output CNN (--kind cnn, --modes 1, no --prune-from)")
    if not args.detour_weight > 0 or (args.detour_weight != 1.0 and args.kind != "cnn"):
        parser.error("--detour-weight is a positive weight, other than 1 for --kind cnn only")
    if args.detour_weight != 1.0 and args.one_way_detour:
        parser.error("--detour-weight finds the two-way detour's rows: not with --one-way-detour, which relabels them")
    if not args.previous_noise >= 0:
        parser.error("--previous-noise is a standard deviation, not negative")
    if not 0.0 <= args.previous_dropout <= 1.0:
        parser.error("--previous-dropout is a share of the rows, in [0, 1]")
    if args.previous_dropout_phases != PHASES and args.previous_dropout == 0:
        parser.error("--previous-dropout-phases names where --previous-dropout's stop is given: give a share too")
    if not 0.0 <= args.previous_shrink <= 1.0:
        parser.error("--previous-shrink is a share of the rows, in [0, 1]")
    if (args.previous_noise != 0.2 or args.previous_dropout > 0 or args.previous_shrink > 0) and not args.previous_command:
        parser.error("--previous-noise, --previous-dropout and --previous-shrink shape --previous-command's last command: give it")
    if not 0.0 <= args.mirror <= 1.0:
        parser.error("--mirror is a share of the rows, in [0, 1]")
    if args.mirror > 0 and (args.kind != "cnn" or args.modes != 1):
        parser.error("--mirror trains a one-output CNN (--kind cnn, --modes 1)")
    if args.mirror > 0 and args.one_way_detour:
        parser.error("--one-way-detour walks around the ball always clockwise, which a mirror turns anticlockwise: not with --mirror")
    if args.prune_from is not None and args.init_from is not None:
        parser.error("--prune-from and --init-from are two starts: name one")
    if args.keep_branches and (args.kind != "cnn" or args.init_from is None):
        parser.error("--keep-branches keeps a CNN start's camera branches: give --kind cnn and --init-from")
    return TrainingConfig.from_namespace(args)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    try:
        device = training_device(args.device)
        dataset = load(args.dataset)
        added = [load(directory) for directory in args.add_dataset]
        for training_data in (dataset, *added):
            refuse_reserved(training_data.seeds(), str(training_data.directory))
            if args.one_way_detour and training_data.teacher not in ONE_WAY_TEACHERS:
                raise DatasetError(f"--one-way-detour relabels the detector teacher's rows; {training_data.directory} is labelled by the {training_data.teacher} teacher")
        # Relabelled in training, the detector teacher's rows are the one-way teacher's.
        teacher = "detector-one-way" if args.one_way_detour else dataset.teacher
        mixed = sorted({d.teacher for d in (dataset, *added)})
        if len(mixed) > 1 and not args.one_way_detour:
            raise DatasetError(f"the datasets were labelled by different teachers ({', '.join(mixed)}): a model learns from one")
        if args.test_dataset:
            # Checked now, read only after training: test data never reaches training.
            test_index = read_index(args.test_dataset)
            if (test_index.get("teacher") or "paper") != teacher:
                raise DatasetError(f"{args.test_dataset} is labelled by the {test_index.get('teacher') or 'paper'} teacher, the training data by the {teacher} one")
            test_seeds = {int(e["seed"]) for e in test_index["episodes"]}
            for training_data in (dataset, *added):
                if test_seeds & set(training_data.seeds()):
                    raise DatasetError(f"{args.test_dataset} shares episodes {sorted(test_seeds & set(training_data.seeds()))} with {training_data.directory}")
        print(f"training data {args.dataset}: {len(dataset.episodes)} episodes, {dataset.rows} rows, hash {dataset.content_hash[:12]}, labelled by the {teacher} teacher", file=sys.stderr)
        for extra in added:
            print(f"  plus {extra.directory}: {len(extra.episodes)} episodes, {extra.rows} rows, hash {extra.content_hash[:12]}", file=sys.stderr)
        print(f"training on {device_name(device)}", file=sys.stderr)
        training = Training(args, dataset, added, device)
    except DatasetError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    checkpoint_dir = args.checkpoint_dir or Path.home() / ".cache" / "dribble" / "checkpoints" / args.out.resolve().name
    checkpoint_dir.mkdir(parents=True, exist_ok=True)
    checkpoint = checkpoint_dir / f"{args.kind}.pt"
    if args.fresh and checkpoint.exists():
        checkpoint.unlink()
    try:
        training.run(checkpoint)
        test = load(args.test_dataset) if args.test_dataset else None
    except DatasetError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2

    print("scoring the kept weights on the training and test data", file=sys.stderr)
    train_episodes = OneWayDetour().relabelled(dataset.episodes)[0] if args.one_way_detour else dataset.episodes
    scores = {"train": score(predict(training.model, args.kind, train_episodes), train_episodes)}
    scores["validation"] = score(predict(training.model, args.kind, training.validation_episodes), training.validation_episodes)
    if test is not None:
        scores["test"] = score(predict(training.model, args.kind, test.episodes), test.episodes)
    record = TrainingRecord(
        dataset=str(args.dataset.name),
        epochs=training.epoch,
        dataset_hash=dataset.content_hash,
        teacher=teacher,
        test_dataset_hash=test.content_hash if test else None,
        added_datasets=[(d.directory.name, d.content_hash) for d in added] or None,
        best_epoch=training.best["epoch"],
        seed=args.seed,
        validation_seeds=training.validation_seeds,
        wall_time_s=round(training.wall_s, 1),
        torch_version=torch.__version__,
        train_error=scores["train"]["error"],
        validation_error=scores["validation"]["error"],
        test_error=scores["test"]["error"] if test else None,
        notes=notes_of(args, device, folded=training.folded_start, widened=training.widened_start),
    )
    training.model.to("cpu")  # exported and plotted from the CPU
    args.out.mkdir(parents=True, exist_ok=True)
    export_policy(training.model, args.out, record, lineage_of(args))
    plot_history(training.history, args.out / "loss_curve.png", f"{args.kind} on {args.dataset.name} ({dataset.rows} rows)")
    (args.out / "scores.json").write_text(json.dumps({"kind": args.kind, "dataset_hash": dataset.content_hash, **scores, "history": training.history}, indent=1) + "\n")
    for name, result in scores.items():
        phases = ", ".join(f"{p} {v['error']:.4f}" for p, v in result["phases"].items() if v["error"] is not None)
        print(f"{name} error {result['error']:.4f} over {result['rows']} rows ({phases})")
    print(f"wrote {args.out / 'policy.toml'} (epoch {training.best['epoch']} of {training.epoch}, {training.wall_s / 60:.1f} min of training)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
