"""What the simulator's camera conditions (sim-harness/src/conditions) do to a thumbnail, at
the thumbnail's scale, in the order the simulator applies them: exposure and vignetting on
linear light (the signal clipped where the sensor saturates), a softer or moving lens as a
3x3 blur (12 camera pixels), contrast around mid-grey, then sensor noise as it survives the
4x4 averaging. One function, for the trainer's augmentation (`train.CameraAugment`, drawn per
row) and the offline look at one effect at a time (`thumbnail_effects.ThumbnailEffect`)."""

from __future__ import annotations

import torch
from torch import nn

GAMMA = 2.2


def apply_camera_effects(
    display: torch.Tensor,
    exposure_ev: torch.Tensor | float = 0.0,
    contrast: torch.Tensor | float = 1.0,
    vignetting: torch.Tensor | float = 0.0,
    blur: torch.Tensor | float = 0.0,
    noise: torch.Tensor | float = 0.0,
) -> torch.Tensor:
    """Display values [N, 1, H, W] in [0, 1] -> the same as the camera would show them.
    Each effect is a number or a [N, 1, 1, 1] tensor (one value a row); `blur` is the share of
    the blurred image (0 or 1 a row), `noise` what is added after the contrast: a tensor of the
    image's shape (noise already drawn) or 0."""
    h, w = display.shape[-2:]
    y = torch.linspace(-1, 1, h).view(1, 1, h, 1)
    x = torch.linspace(-1, 1, w).view(1, 1, 1, w)
    falloff = 1 - vignetting * (x * x + y * y) / 2
    linear = display.clamp(0, 1) ** GAMMA * falloff * torch.pow(torch.as_tensor(2.0), torch.as_tensor(exposure_ev))
    shown = linear.clamp(0, 1) ** (1 / GAMMA)
    blurred = nn.functional.avg_pool2d(nn.functional.pad(shown, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    shown = blur * blurred + (1 - blur) * shown
    shown = 0.5 + (shown - 0.5) * contrast
    return (shown + noise).clamp(0.0, 1.0)
