"""A shipped model's float weights back into a PyTorch network, to start training from it.

A training checkpoint (`.pt`) lives under ~/.cache/dribble and is not committed; the shipped
model directory is (its `policy.toml` and ONNX network). DAgger warm-starts from the base's
kept weights, so a machine without the base's checkpoint would have to train the base again
(about 20 minutes for the CNN) only to get back weights the ONNX file already holds.

`export.py` writes each parameter as an ONNX initializer named by its PyTorch state-dict key,
unchanged (no folding: the networks have no batch norm), so the import is a name-for-name
copy. It is strict: every parameter must be found with its shape and float32 type, and an
initializer without a parameter is refused too, so a file that does not hold exactly this
network's weights is an error, never a partly random start. Only one-network float models
whose parameters are all initializers qualify (the CNN and the two-hypothesis CNN); the
H-CNN's gate and the R-CNN's exported LSTM do not map one to one and are refused with that
reason (their checkpoints are needed).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper
from torch import nn

from .networks import set_standardise


class ShippedWeightsError(ValueError):
    """The model directory does not hold exactly this network's float weights."""


def manifest_of(path: Path) -> Path:
    """The `policy.toml` that `path` names: the file itself or the one in a model directory."""
    path = Path(path)
    manifest = path / "policy.toml" if path.is_dir() else path
    if manifest.name != "policy.toml" or not manifest.is_file():
        raise ShippedWeightsError(f"{path}: not a model directory or its policy.toml")
    return manifest


def is_shipped_model(path: Path) -> bool:
    """Whether `path` names a shipped model (a directory with policy.toml, or that file)."""
    path = Path(path)
    return (path.is_dir() and (path / "policy.toml").is_file()) or path.name == "policy.toml"


def network_of(path: Path, kind: str | None = None) -> Path:
    """The one float network file of the model at `path` (of `kind`, where given), or why not."""
    manifest_path = manifest_of(path)
    manifest = tomllib.loads(manifest_path.read_text())
    if kind is not None and manifest.get("kind") != kind:
        raise ShippedWeightsError(f"{manifest_path}: a {manifest.get('kind')} model, this run trains a {kind}")
    if manifest.get("precision", "float32") != "float32":
        raise ShippedWeightsError(f"{manifest_path}: precision {manifest['precision']}; only float models can be trained on")
    networks = manifest.get("networks", [])
    if len(networks) != 1:
        raise ShippedWeightsError(
            f"{manifest_path}: {len(networks)} networks; only one-network models map onto one PyTorch module "
            "(start from the training checkpoint instead)"
        )
    return manifest_path.parent / networks[0]


def shipped_initializers(path: Path, kind: str) -> tuple[Path, dict[str, np.ndarray]]:
    """The manifest of the one-network float model of `kind` at `path` and its network's
    initializers by name (`network_of` refuses any other model)."""
    network = network_of(path, kind)
    graph = onnx.load(str(network)).graph
    return manifest_of(path), {tensor.name: numpy_helper.to_array(tensor) for tensor in graph.initializer}


def require_every_parameter(model: nn.Module, values: dict[str, np.ndarray], manifest_path: Path) -> None:
    """Refuses `values` that lack a parameter of `model`."""
    missing = sorted(set(model.state_dict()) - set(values))
    if missing:
        raise ShippedWeightsError(
            f"{manifest_path}: no initializer for the parameters {', '.join(missing[:4])}"
            f"{' ...' if len(missing) > 4 else ''} (start from the training checkpoint instead)"
        )


def load_strictly(model: nn.Module, values: dict[str, np.ndarray], manifest_path: Path) -> None:
    """Loads `values` into `model`: every parameter must be there, float32, of its shape."""
    require_every_parameter(model, values, manifest_path)
    state = model.state_dict()
    loaded = {}
    for name, expected in state.items():
        value = values[name]
        if value.dtype != np.float32 or tuple(value.shape) != tuple(expected.shape):
            raise ShippedWeightsError(
                f"{manifest_path}: {name} is {value.dtype} {list(value.shape)}, the network's is float32 {list(expected.shape)}"
            )
        loaded[name] = torch.from_numpy(value.copy())
    model.load_state_dict(loaded, strict=True)


def load_shipped_weights(model: nn.Module, path: Path, kind: str) -> None:
    """Copies the float weights of the model at `path` into `model`, strictly (module doc)."""
    manifest_path, initializers = shipped_initializers(path, kind)
    require_every_parameter(model, initializers, manifest_path)
    extra = sorted(set(initializers) - set(model.state_dict()))
    if extra:
        raise ShippedWeightsError(f"{manifest_path}: initializers {', '.join(extra[:4])} are no parameter of this network")
    load_strictly(model, initializers, manifest_path)
    set_standardise(model, standardised_manifest(manifest_path))


def standardised_manifest(path: Path) -> bool:
    """Whether the model at `path` has the controller standardise its thumbnails."""
    manifest = tomllib.loads(manifest_of(path).read_text())
    return bool(manifest.get("normalisation", {}).get("standardise", False))


def load_pruned_weights(model: nn.Module, path: Path) -> dict[str, list[int]]:
    """Copies into the CNN `model` the weights of the wider shipped CNN at `path`, pruned to
    `model`'s filter counts, and returns the filters kept per convolution.

    Filter pruning by magnitude (Li et al., "Pruning filters for efficient ConvNets", ICLR
    2017): each convolution keeps its filters with the largest L1 norms, in their order; the
    next convolution keeps the input channels of the filters kept before it, and the first
    dense layer the columns that the kept second-layer filters feed (the flattening is channel
    by channel: `cells` columns each, 7 x 10 for the top camera and 4 x 5 for the bottom). A
    start for distilling a narrower network (issue 29): it begins near the wide network's
    function instead of at random. The model at `path` must be a one-network float CNN at
    least as wide in every layer; `model` must be a `CNN` (one command)."""
    manifest_path, initializers = shipped_initializers(path, "cnn")
    require_every_parameter(model, initializers, manifest_path)
    state = model.state_dict()
    pruned: dict[str, np.ndarray] = {}
    kept: dict[str, list[int]] = {}
    columns: list[np.ndarray] = []
    offset = 0
    for branch, cells in (("top", 7 * 10), ("bottom", 4 * 5)):
        first, second = f"features.{branch}.0", f"features.{branch}.3"
        w1, w2 = initializers[f"{first}.weight"], initializers[f"{second}.weight"]
        want1, want2 = state[f"{first}.weight"].shape[0], state[f"{second}.weight"].shape[0]
        if want1 > w1.shape[0] or want2 > w2.shape[0]:
            raise ShippedWeightsError(
                f"{manifest_path}: the {branch} camera has {w1.shape[0]},{w2.shape[0]} filters, fewer than "
                f"the {want1},{want2} this run trains (pruning only removes filters)"
            )
        keep1 = strongest_filters(w1, want1)
        w2 = w2[:, keep1]
        keep2 = strongest_filters(w2, want2)
        pruned[f"{first}.weight"] = w1[keep1]
        pruned[f"{first}.bias"] = initializers[f"{first}.bias"][keep1]
        pruned[f"{second}.weight"] = w2[keep2]
        pruned[f"{second}.bias"] = initializers[f"{second}.bias"][keep2]
        kept[f"{branch} first"], kept[f"{branch} second"] = keep1.tolist(), keep2.tolist()
        columns.extend(offset + c * cells + np.arange(cells) for c in keep2)
        offset += initializers[f"{second}.weight"].shape[0] * cells
    pruned["head.0.weight"] = initializers["head.0.weight"][:, np.concatenate(columns)]
    for name in ("head.0.bias", "head.2.weight", "head.2.bias"):
        pruned[name] = initializers[name]
    load_strictly(model, pruned, manifest_path)
    return kept


def strongest_filters(weights: np.ndarray, count: int) -> np.ndarray:
    """The indices of the `count` filters (first axis) with the largest L1 norms, ascending;
    ties keep the earlier filter (a stable sort), so the choice is deterministic."""
    norms = np.abs(weights).reshape(weights.shape[0], -1).sum(axis=1)
    order = np.argsort(-norms, kind="stable")
    return np.sort(order[:count])
