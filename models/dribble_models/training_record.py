"""What a trained model's manifest says of its run: the notes (every option that shaped it, in
words), its lineage (the models it started from, was distilled from or took convolutions
from, each with the hash of its network file)."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from .dataset import PHASES, DatasetError, read_index
from .manifest import Lineage, ModelReference
from .networks import PAPER_FILTERS
from .one_way_detour import AT_BALL_M
from .shipped_weights import is_shipped_model, network_of

if TYPE_CHECKING:
    from .train import TrainingConfig


def device_name(device: torch.device) -> str:
    return f"cuda ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else "the CPU"


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def start_sha256(path: Path) -> str:
    """The hash that names a start: the checkpoint file's, or a shipped model's network file's."""
    return file_sha256(network_of(path) if is_shipped_model(path) else path)


def lineage_of(args: TrainingConfig) -> Lineage | None:
    """The `[lineage]` of the model a run writes: the model it started from (its kept weights,
    or pruned), the one whose commands were its labels, and the CNN whose convolutions an
    R-CNN took."""
    def reference(path: Path, how: str | None = None) -> ModelReference:
        return ModelReference(str(path), start_sha256(path)[:12], how)

    started = None
    if args.init_from is not None:
        started = reference(args.init_from, "camera branches kept as they are, dense layers trained" if args.keep_branches else None)
    elif args.prune_from is not None:
        started = reference(args.prune_from, "pruned to these filters, largest L1 norms kept")
    distilled = reference(args.distill_from) if args.distill_from is not None else None
    features = None
    if args.features_from is not None:
        features = reference(args.features_from, "kept fixed" if args.freeze_features else "trained on")
    return Lineage(started, distilled, features) if started or distilled or features else None


def added_description(directory: Path) -> str:
    """An added dataset's name and who drove its episodes: a policy (a DAgger round's
    `dribble record --driver`, whose dataset.json names the driver) or the expert."""
    try:
        driven = "policy-driven" if read_index(directory).get("driver") else "expert-driven"
    except DatasetError:
        return directory.name
    return f"{directory.name} ({driven})"


def dropout_phases(args: TrainingConfig) -> str:
    """Where `--previous-dropout-phases` narrows the stop to some of the teacher's phases, which."""
    if args.previous_dropout_phases == PHASES:
        return ""
    return " in the teacher's " + " and ".join(args.previous_dropout_phases) + " phase" + ("s" if len(args.previous_dropout_phases) > 1 else "")


def notes_of(args: TrainingConfig, device: torch.device | None = None, folded: bool = False, widened: bool = False) -> str:
    parts = [
        f"Adam lr {args.lr}",
        f"batch {args.batch_size}" if args.kind != "rcnn" else f"{args.lanes} lanes of {args.window}-step windows",
        f"epoch fraction {args.epoch_fraction}",
        f"{args.validation_episodes} validation episodes",
    ]
    if args.modes != 1:
        parts.append(f"{args.modes} command hypotheses, winner-takes-all with a learned choice")
    if args.filters != PAPER_FILTERS:
        f = args.filters
        parts.append(f"filters {f.text()} (top {f[0]} then {f[1]}, bottom {f[2]} then {f[3]}; the paper's {PAPER_FILTERS.text()})")
    if args.kind == "hcnn":
        parts.append(f"K {args.clusters} (k-means on {args.kmeans_rows} sampled rows)")
    parts.append("augmented" if args.augment else "no augmentation")
    if args.camera_augment > 0:
        strength = {
            "standard": "",
            "strong": ", strong ranges",
            "motion-and-light": ", the camera's turn (directional smear, rolling-shutter skew), patches of shadow and sunlight",
        }[args.camera_augment_strength]
        parts.append(f"camera conditions augmented on {args.camera_augment:.0%} of the rows (CameraAugment: exposure, contrast, vignetting, blur, noise{strength})")
    if args.standardise_input:
        parts.append("each thumbnail standardised on its own before the network ([normalisation] standardise)")
        if folded:
            parts.append("a start trained on pixel / 255 has its first layers re-expressed at the training rows' typical level and spread (fold_typical_level)")
    if args.balance_phases:
        parts.append("phase-balanced sampling")
    if args.detour_weight != 1.0:
        parts.append(f"the teacher's detour rows at the ball (within {AT_BALL_M:g} m) sampled {args.detour_weight:g} times as often, with the teacher's labels")
    if args.add_dataset:
        parts.append(f"plus every episode of {', '.join(added_description(d) for d in args.add_dataset)} (expert-labelled)")
    if args.add_dataset and args.cut_stalls is not None:
        parts.append(f"stalls in them cut after {args.cut_stalls:g} s (dribble_models.stalls)")
    if args.init_from is not None:
        parts.append(f"started from the kept weights of {args.init_from} (sha256 {start_sha256(args.init_from)[:12]})")
        if widened:
            parts.append(
                "a one-output start's head widened to the hypotheses (ModalCNN.widened: each its command, sideways moved "
                "by +-0.5 between them, the choice tied: it begins with the start's commands)"
            )
    if args.prune_from is not None:
        parts.append(f"started from {args.prune_from} (sha256 {start_sha256(args.prune_from)[:12]}) pruned to these filters, largest L1 norms kept")
    if args.distill_from is not None:
        rows = "on the rows of camera-clean episodes (clean or robots only) and, where recorded, the clean twins of conditioned rows; the teacher's labels elsewhere" if args.distill_camera_clean else "for each training row (its clean twin where recorded)"
        validated = "validated on them by the same rule" if args.validate_distilled else "validated on the teacher's"
        parts.append(f"distilled: trained on the commands of {args.distill_from} (sha256 {start_sha256(args.distill_from)[:12]}) {rows}, {validated}")
    if args.previous_command:
        parts.append(
            f"the last command sent is a third input ([inputs] previous; PreviousCommandCNN): on each row the command executed "
            f"at the row before, perturbed on training rows by Gaussian noise of {args.previous_noise:g}"
            + (f", a stop in its place on {args.previous_dropout:.0%} of them{dropout_phases(args)}" if args.previous_dropout > 0 else "")
            + (f", faded toward a stop (scaled by a uniform factor in [0, 1), its direction kept) on {args.previous_shrink:.0%} of them" if args.previous_shrink > 0 else "")
        )
    if args.keep_branches:
        parts.append("the start's camera branches kept as they are, only the dense layers trained")
    if args.mirror > 0:
        parts.append(f"{args.mirror:.0%} of the training rows mirrored left to right, the command's sideways and turn negated (the last command's too): the row of the mirror state (augmentation.mirrored)")
    if args.one_way_detour:
        parts.append("the teacher's detour around the ball relabelled to go one way, clockwise, on training and validation rows (dribble_models.one_way_detour)")
    if args.features_from is not None:
        how = "kept fixed" if args.freeze_features else "trained on"
        parts.append(f"convolutions from the CNN {args.features_from} (sha256 {start_sha256(args.features_from)[:12]}), {how}")
    if device is not None and device.type != "cpu":
        parts.append(f"trained on {device_name(device)}")
    parts.append("train_error over every episode of the training dataset (validation ones too)")
    return "; ".join(parts)
