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


def load_shipped_weights(model: nn.Module, path: Path, kind: str) -> None:
    """Copies the float weights of the model at `path` into `model`, strictly (module doc)."""
    network = network_of(path, kind)
    manifest_path = manifest_of(path)
    graph = onnx.load(str(network)).graph
    initializers = {tensor.name: numpy_helper.to_array(tensor) for tensor in graph.initializer}
    state = model.state_dict()
    missing = sorted(set(state) - set(initializers))
    if missing:
        raise ShippedWeightsError(
            f"{manifest_path}: no initializer for the parameters {', '.join(missing[:4])}"
            f"{' ...' if len(missing) > 4 else ''} (start from the training checkpoint instead)"
        )
    extra = sorted(set(initializers) - set(state))
    if extra:
        raise ShippedWeightsError(f"{manifest_path}: initializers {', '.join(extra[:4])} are no parameter of this network")
    loaded = {}
    for name, expected in state.items():
        value = initializers[name]
        if value.dtype != np.float32 or tuple(value.shape) != tuple(expected.shape):
            raise ShippedWeightsError(
                f"{manifest_path}: {name} is {value.dtype} {list(value.shape)}, the network's is float32 {list(expected.shape)}"
            )
        loaded[name] = torch.from_numpy(value.copy())
    model.load_state_dict(loaded, strict=True)
