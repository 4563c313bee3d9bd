"""The three policy networks of the paper, as DESIGN.md specifies them.

Each camera has a branch: conv 5x5 stride 2 padding 2, ReLU, max-pool 2x2, twice (16 then 32
filters for the top camera, 8 then 16 for the bottom one). The flattened branches make
32*7*10 + 16*4*5 = 2560 features.

Beyond the paper, the CNN may be narrower (`Filters`): the same layers with fewer filters,
for the Nao V5's Atom, whose 2 ms tick the paper's widths miss (issue 29: the int8 forward's
multiply-adds alone cost more instructions than the tick allows there).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from . import contract
from .gating import nearest_cluster

class Filters(tuple):
    """The four convolutions' filter counts: top first and second, bottom first and second."""

    def __new__(cls, top_first: int, top_second: int, bottom_first: int, bottom_second: int) -> "Filters":
        counts = (top_first, top_second, bottom_first, bottom_second)
        if any(int(c) != c or c < 1 for c in counts):
            raise ValueError(f"filter counts are positive integers, not {counts}")
        return super().__new__(cls, tuple(int(c) for c in counts))

    @classmethod
    def parse(cls, text: str) -> "Filters":
        """`16,32,8,16` (top first, top second, bottom first, bottom second)."""
        try:
            return cls(*(int(part) for part in text.split(",")))
        except (TypeError, ValueError) as error:
            raise ValueError(f"filters are four counts such as 16,32,8,16, not {text!r} ({error})") from None

    @property
    def features(self) -> int:
        """The flattened branches' length: top second * 7 * 10 + bottom second * 4 * 5."""
        return self[1] * 7 * 10 + self[3] * 4 * 5

    def text(self) -> str:
        return ",".join(str(c) for c in self)


#: The paper's widths.
PAPER_FILTERS = Filters(16, 32, 8, 16)
FEATURES = PAPER_FILTERS.features


def camera_branch(first: int, second: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(1, first, kernel_size=5, stride=2, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(2),
        nn.Conv2d(first, second, kernel_size=5, stride=2, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(2),
        nn.Flatten(),
    )


def standardised(images: torch.Tensor) -> torch.Tensor:
    """Scaled thumbnails [B,1,H,W] (`pixel * INPUT_SCALE`, perhaps augmented) standardised each
    on its own: `(x - mean) / max(spread, floor)`, the controller's rule in scaled units
    (`contract.network_input` in pixel levels; the scale cancels)."""
    mean = images.mean(dim=(-2, -1), keepdim=True)
    spread = images.var(dim=(-2, -1), keepdim=True, unbiased=False).sqrt()
    floor = contract.STANDARDISE_FLOOR_LEVELS * contract.INPUT_SCALE
    return (images - mean) / spread.clamp(min=floor)


class CameraFeatures(nn.Module):
    """Both camera branches, flattened and concatenated: [B,1,120,160], [B,1,60,80] -> [B,2560].

    `standardise_input` (not a parameter: the manifest's `standardise` carries it) makes the
    branches standardise their scaled inputs first, as the controller does before the network
    for a standardised policy; export turns it off (`export.network_only`), since the ONNX
    network receives what the controller already standardised."""

    def __init__(self, filters: Filters = PAPER_FILTERS) -> None:
        super().__init__()
        self.filters = filters
        self.top = camera_branch(filters[0], filters[1])
        self.bottom = camera_branch(filters[2], filters[3])
        self.standardise_input = False

    def forward(self, top: torch.Tensor, bottom: torch.Tensor) -> torch.Tensor:
        if self.standardise_input:
            top, bottom = standardised(top), standardised(bottom)
        return torch.cat([self.top(top), self.bottom(bottom)], dim=1)


def standardises(model: nn.Module) -> bool:
    """Whether the model standardises its thumbnails (`CameraFeatures.standardise_input`)."""
    return any(m.standardise_input for m in model.modules() if isinstance(m, CameraFeatures))


def set_standardise(model: nn.Module, standardise: bool) -> None:
    """Makes every camera branch of `model` standardise its inputs, or not."""
    for module in model.modules():
        if isinstance(module, CameraFeatures):
            module.standardise_input = standardise


class CNN(nn.Module):
    """Features, dense 128 ReLU, dense 3: (top, bottom) -> command [B,3]."""

    def __init__(self, filters: Filters = PAPER_FILTERS) -> None:
        super().__init__()
        self.features = CameraFeatures(filters)
        self.head = nn.Sequential(nn.Linear(filters.features, 128), nn.ReLU(), nn.Linear(128, 3))

    def forward(self, top: torch.Tensor, bottom: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(top, bottom))


class PreviousCommandCNN(nn.Module):
    """Beyond the paper: the CNN with the last command the controller sent as a third input
    (`[inputs] previous`, DESIGN.md "Policies"), into its hidden layer:
    (top, bottom, previous [B,3]) -> command [B,3].

    Why: beside the ball, facing what it cannot read, a reactive CNN cannot tell which way
    round the ball it was going; the teacher's two detours average to a stop and the robot
    stands (docs/src/history/previous-command.md). The command it sent last is known on the
    robot and breaks the tie the way it was already moving. `previous` is each component
    normalised and clamped to [-1, 1], a stop where the controller sent one, zero at an
    episode's start (`Episode.previous` for recorded rows).
    384 multiply-adds more than the CNN."""

    def __init__(self, features: CameraFeatures | None = None) -> None:
        super().__init__()
        self.features = features if features is not None else CameraFeatures()
        self.hidden = nn.Linear(self.features.filters.features + 3, 128)
        self.out = nn.Linear(128, 3)

    @staticmethod
    def from_cnn(cnn: CNN) -> "PreviousCommandCNN":
        """Begins as `cnn`'s function: its branches and dense layers, the last command's
        weights zero."""
        model = PreviousCommandCNN(cnn.features)
        first, last = cnn.head[0], cnn.head[2]
        with torch.no_grad():
            model.hidden.weight.zero_()
            model.hidden.weight[:, : first.in_features] = first.weight
            model.hidden.bias.copy_(first.bias)
            model.out.load_state_dict(last.state_dict())
        return model

    def head(self, features: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        return self.out(torch.relu(self.hidden(torch.cat([features, previous], dim=1))))

    def forward(self, top: torch.Tensor, bottom: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(top, bottom), previous)


class ModalCNN(nn.Module):
    """Beyond the paper: the CNN with `modes` command hypotheses and a learned choice among
    them (winner-takes-all training, Guzman-Rivera et al. 2012; Rupprecht et al. 2017).

    Why: where the ball is out of sight the expert turns toward it, choosing the direction
    from ground truth. An image does not say which way; a regression network answers the
    mean of "left" and "right", a turn near zero, and the robot stands. With hypotheses,
    one learns "turn left", another "turn right", and the choice picks one: a decisive search.

    Exported as a CNN: the choice (the hypothesis with the largest logit; the mean of tied
    ones) is part of the graph, so the controller runs it unchanged as `kind = "cnn"`."""

    def __init__(self, modes: int = 2, filters: Filters = PAPER_FILTERS) -> None:
        super().__init__()
        self.modes = modes
        self.features = CameraFeatures(filters)
        self.trunk = nn.Sequential(nn.Linear(filters.features, 128), nn.ReLU())
        self.hypotheses = nn.Linear(128, 3 * modes)
        self.choice = nn.Linear(128, modes)

    @staticmethod
    def widened(cnn: CNN, modes: int = 2, spread: float = 0.5, component: int = 1) -> "ModalCNN":
        """A ModalCNN that starts as `cnn`: its features and hidden layer, each hypothesis
        `cnn`'s output with `component` of the command (1: sideways) moved by a share of
        `spread` (the shares, -1..1 evenly, sum to zero), and a choice of zero weights.
        The choice ties, so the network sends the hypotheses' mean, `cnn`'s command, until
        it learns; the offsets break the hypotheses' symmetry along the component where the
        teacher's two answers differ (its detour around the ball goes left or right), so
        that winner-takes-all can give each side its own hypothesis. (On the host model's
        recipe it split the commands into a main answer and a rare one instead:
        docs/src/history/two-hypotheses-at-the-ball.md.)"""
        if modes < 2:
            raise ValueError("a widened head has two hypotheses or more")
        model = ModalCNN(modes, cnn.features.filters)
        model.features.load_state_dict(cnn.features.state_dict())
        model.trunk.load_state_dict(cnn.head[:2].state_dict())
        last = cnn.head[2]
        offsets = torch.linspace(spread, -spread, modes)
        with torch.no_grad():
            model.hypotheses.weight.copy_(last.weight.repeat(modes, 1))
            bias = last.bias.repeat(modes, 1)
            bias[:, component] += offsets
            model.hypotheses.bias.copy_(bias.reshape(-1))
            model.choice.weight.zero_()
            model.choice.bias.zero_()
        model.features.standardise_input = cnn.features.standardise_input
        return model

    def forward_all(self, top: torch.Tensor, bottom: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(hypotheses [B,modes,3], choice logits [B,modes])."""
        hidden = self.trunk(self.features(top, bottom))
        return self.hypotheses(hidden).view(-1, self.modes, 3), self.choice(hidden)

    def forward(self, top: torch.Tensor, bottom: torch.Tensor) -> torch.Tensor:
        hypotheses, logits = self.forward_all(top, bottom)
        chosen = (logits == logits.max(dim=1, keepdim=True).values).to(hypotheses.dtype)
        return (hypotheses * chosen.unsqueeze(2)).sum(dim=1) / chosen.sum(dim=1, keepdim=True)


class RCNN(nn.Module):
    """Features, an LSTM of 64 units, dense 3, over sequences [B,T,1,H,W]."""

    def __init__(self, hidden: int = contract.LSTM_UNITS) -> None:
        super().__init__()
        self.features = CameraFeatures()
        self.lstm = nn.LSTM(FEATURES, hidden, batch_first=True)
        self.head = nn.Linear(hidden, 3)

    def forward(
        self,
        top: torch.Tensor,
        bottom: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        batch, steps = top.shape[:2]
        features = self.features(top.flatten(0, 1), bottom.flatten(0, 1))
        out, state = self.lstm(features.view(batch, steps, -1), state)
        return self.head(out), state

    def zero_state(self, batch: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
        """The LSTM's zero state for `batch` sequences, where the weights are (CPU or GPU)."""
        zeros = torch.zeros(1, batch, self.lstm.hidden_size, device=self.head.weight.device)
        return zeros, zeros.clone()


class RCNNStep(nn.Module):
    """One R-CNN step for the robot: (top, bottom, h_in, c_in) -> (command, h_out, c_out),
    each state [1,1,64] (layers, batch, units)."""

    def __init__(self, rcnn: RCNN) -> None:
        super().__init__()
        self.rcnn = rcnn

    def forward(self, top, bottom, h_in, c_in):
        features = self.rcnn.features(top, bottom).unsqueeze(1)
        out, (h_out, c_out) = self.rcnn.lstm(features, (h_in, c_in))
        return self.rcnn.head(out[:, 0]), h_out, c_out


class HCNN(nn.Module):
    """K CNNs and K centroids of the 10-value histogram feature; the nearest centroid picks
    the CNN for each sample."""

    def __init__(self, centroids: np.ndarray) -> None:
        super().__init__()
        self.centroids = np.asarray(centroids, dtype=np.float32)
        self.experts = nn.ModuleList(CNN() for _ in range(len(self.centroids)))

    def select(self, top_u8: np.ndarray, bottom_u8: np.ndarray) -> int:
        return nearest_cluster(top_u8, bottom_u8, self.centroids)

    def forward_u8(self, top_u8: np.ndarray, bottom_u8: np.ndarray) -> tuple[torch.Tensor, int]:
        """One sample from u8 thumbnails: (command [1,3], chosen network)."""
        k = self.select(top_u8, bottom_u8)
        top, bottom = to_network_input(top_u8, bottom_u8)
        return self.experts[k](top, bottom), k


def to_network_input(top_u8: np.ndarray, bottom_u8: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """u8 thumbnails [..., H, W] -> f32 tensors [N,1,H,W] scaled as the robot scales them."""
    def convert(thumbnails: np.ndarray, shape: tuple[int, int]) -> torch.Tensor:
        array = np.asarray(thumbnails, dtype=np.uint8).reshape(-1, 1, *shape)
        return torch.from_numpy(array.astype(np.float32) * np.float32(contract.INPUT_SCALE))

    return convert(top_u8, contract.TOP_SHAPE), convert(bottom_u8, contract.BOTTOM_SHAPE)
