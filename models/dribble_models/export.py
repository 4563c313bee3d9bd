"""Export to single-file ONNX (weights inside, opset 17) with DESIGN.md's names, plus the
manifest. `export_policy` is what training calls at the end."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import onnx
import torch

from . import contract
from .manifest import Lineage, Manifest, TrainingRecord
from .networks import CNN, HCNN, RCNN, ModalCNN, PreviousCommandCNN, RCNNStep, set_standardise, standardises


@contextmanager
def network_only(model: torch.nn.Module) -> Iterator[None]:
    """The network without the input standardisation the controller does before it: what
    the ONNX file holds."""
    standardise = standardises(model)
    set_standardise(model, False)
    try:
        yield
    finally:
        set_standardise(model, standardise)


def _example_inputs() -> tuple[torch.Tensor, torch.Tensor]:
    return torch.rand(1, 1, *contract.TOP_SHAPE), torch.rand(1, 1, *contract.BOTTOM_SHAPE)


def _export(module: torch.nn.Module, args: tuple, path: Path, inputs: list[str], outputs: list[str]) -> Path:
    module.eval()
    path = Path(path)
    # The TorchScript exporter writes one self-contained file for models this small and keeps
    # the exact input and output names; fixed shapes let tract plan once.
    torch.onnx.export(
        module,
        args,
        str(path),
        input_names=inputs,
        output_names=outputs,
        opset_version=contract.OPSET,
        dynamo=False,
        do_constant_folding=True,
    )
    model = onnx.load(str(path))
    onnx.checker.check_model(model, full_check=True)
    return path


def export_cnn(model: CNN | ModalCNN, path: Path) -> Path:
    return _export(
        model,
        _example_inputs(),
        path,
        [contract.TOP_INPUT, contract.BOTTOM_INPUT],
        [contract.COMMAND_OUTPUT],
    )


def export_previous_command_cnn(model: PreviousCommandCNN, path: Path) -> Path:
    # A last command unlike the zero of an episode's start, so that the tracer keeps its path.
    previous = torch.tensor([[0.5, -0.25, 0.75]])
    return _export(
        model,
        (*_example_inputs(), previous),
        path,
        [contract.TOP_INPUT, contract.BOTTOM_INPUT, contract.PREVIOUS_INPUT],
        [contract.COMMAND_OUTPUT],
    )


def export_rcnn_step(model: RCNN, path: Path) -> Path:
    units = model.lstm.hidden_size
    # Distinct example tensors for h and c: passing one tensor for both lets the tracer merge
    # the two inputs, and the exported step then feeds c where h belongs.
    h_example = torch.full((1, 1, units), 0.25)
    c_example = torch.full((1, 1, units), -0.5)
    return _export(
        RCNNStep(model),
        (*_example_inputs(), h_example, c_example),
        path,
        [contract.TOP_INPUT, contract.BOTTOM_INPUT, contract.H_INPUT, contract.C_INPUT],
        [contract.COMMAND_OUTPUT, contract.H_OUTPUT, contract.C_OUTPUT],
    )


def export_policy(model: CNN | ModalCNN | PreviousCommandCNN | HCNN | RCNN, directory: Path, training: TrainingRecord, lineage: Lineage | None = None) -> Path:
    """Writes the model's ONNX file(s) and `policy.toml` into `directory`; returns the manifest."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    standardise = standardises(model)
    with network_only(model):
        manifest = _export_networks(model, directory, training)
    manifest.standardise = standardise
    manifest.lineage = lineage
    return manifest.write(directory)


def _export_networks(model: CNN | ModalCNN | PreviousCommandCNN | HCNN | RCNN, directory: Path, training: TrainingRecord) -> Manifest:
    if isinstance(model, HCNN):
        networks = [f"cnn{k}.onnx" for k in range(len(model.experts))]
        for expert, name in zip(model.experts, networks):
            export_cnn(expert, directory / name)
        manifest = Manifest("hcnn", networks, training, centroids=model.centroids.tolist())
    elif isinstance(model, RCNN):
        export_rcnn_step(model, directory / "policy.onnx")
        manifest = Manifest("rcnn", ["policy.onnx"], training, lstm_units=model.lstm.hidden_size)
    elif isinstance(model, PreviousCommandCNN):
        export_previous_command_cnn(model, directory / "policy.onnx")
        manifest = Manifest("cnn", ["policy.onnx"], training, previous=True)
    elif isinstance(model, (CNN, ModalCNN)):
        export_cnn(model, directory / "policy.onnx")
        manifest = Manifest("cnn", ["policy.onnx"], training)
    else:
        raise TypeError(f"cannot export a {type(model).__name__}")
    return manifest
