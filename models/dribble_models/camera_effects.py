"""What the simulator's camera conditions (sim-harness/src/conditions) do to a thumbnail, at
the thumbnail's scale, in the order the simulator applies them: the scene's light (soft
shadows and bright patches, `shading`) and the camera's motion during the exposure (a
directional smear and rolling-shutter skew, `CameraMotion`) on linear light, exposure and
vignetting (the signal clipped where the sensor saturates), a softer lens as a 3x3 blur
(12 camera pixels), contrast around mid-grey, then sensor noise as it survives the 4x4
averaging. One function, for the trainer's augmentation (`augmentation.CameraAugment`, drawn per
row) and the offline look at one effect at a time (`thumbnail_effects.ThumbnailEffect`)."""

from __future__ import annotations

from dataclasses import dataclass

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
    shading: torch.Tensor | float = 1.0,
    motion: "CameraMotion | None" = None,
) -> torch.Tensor:
    """Display values [N, 1, H, W] in [0, 1] -> the same as the camera would show them.
    Each effect is a number or a [N, 1, 1, 1] tensor (one value a row); `blur` is the share of
    the blurred image (0 or 1 a row), `noise` what is added after the contrast: a tensor of the
    image's shape (noise already drawn) or 0; `shading` multiplies the scene's linear light
    (a number or a map of the image's shape, `light_patches`); `motion` smears it."""
    h, w = display.shape[-2:]
    y = torch.linspace(-1, 1, h).view(1, 1, h, 1)
    x = torch.linspace(-1, 1, w).view(1, 1, 1, w)
    falloff = 1 - vignetting * (x * x + y * y) / 2
    scene = display.clamp(0, 1) ** GAMMA * shading
    if motion is not None:
        scene = motion.smear(scene)
    linear = scene * falloff * torch.pow(torch.as_tensor(2.0), torch.as_tensor(exposure_ev))
    shown = linear.clamp(0, 1) ** (1 / GAMMA)
    blurred = nn.functional.avg_pool2d(nn.functional.pad(shown, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    shown = blur * blurred + (1 - blur) * shown
    shown = 0.5 + (shown - 0.5) * contrast
    return (shown + noise).clamp(0.0, 1.0)


@dataclass
class CameraMotion:
    """The camera turning during one frame, at a thumbnail's scale: over the exposure the
    image moves `length_px` thumbnail pixels along `angle` (radians from the image's x axis;
    a turn of the body or head moves it along x, a nod along y), and a rolling shutter, which
    reads the rows one after another while the camera turns, shifts the bottom row
    `skew_px` along x from the top one. Each a [N] tensor, one value a row (0: still).

    The simulator's motion-blur condition at severity 3 (a 30 ms exposure and 30 ms readout
    while turning at 1 rad/s; a focal length of about 540 camera pixels, 61 degrees over 640)
    moves the top camera's image about 16 camera pixels, 4 thumbnail pixels, during the
    exposure and skews it about as much during the readout; severity 5 (50 ms) about 7."""

    length_px: torch.Tensor
    angle: torch.Tensor
    skew_px: torch.Tensor
    samples: int = 9

    def smear(self, image: torch.Tensor) -> torch.Tensor:
        """[N, 1, H, W] linear light -> the same averaged along each row's motion (borders
        repeated), `samples` points along the line; still rows are left as they are."""
        moving = (self.length_px != 0) | (self.skew_px != 0)
        if not bool(moving.any()):
            return image
        out = image.clone()
        out[moving] = _smear(image[moving], self.length_px[moving], self.angle[moving], self.skew_px[moving], self.samples)
        return out


def _smear(image: torch.Tensor, length_px: torch.Tensor, angle: torch.Tensor, skew_px: torch.Tensor, samples: int) -> torch.Tensor:
    """`CameraMotion.smear` on every row of `image`."""
    n, _, h, w = image.shape
    gy, gx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
    # Thumbnail pixels -> grid_sample's [-1, 1] units (align_corners: the outer pixels' centres).
    to_x, to_y = 2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)
    dx = (length_px * torch.cos(angle) * to_x).view(n, 1, 1)
    dy = (length_px * torch.sin(angle) * to_y).view(n, 1, 1)
    skew = skew_px.view(n, 1, 1) * (gy / 2) * to_x
    total = torch.zeros_like(image)
    for s in torch.linspace(-0.5, 0.5, samples):
        grid = torch.stack((gx + skew + s * dx, (gy + s * dy).expand(n, h, w)), dim=-1)
        total += nn.functional.grid_sample(image, grid, mode="bilinear", padding_mode="border", align_corners=True)
    return total / samples


def light_patches(
    n: int,
    shape: tuple[int, int],
    generator: torch.Generator,
    chance: torch.Tensor,
    patches: int = 3,
    shadow_share: tuple[float, float] = (0.15, 0.6),
    spot_gain: tuple[float, float] = (0.25, 0.9),
) -> torch.Tensor:
    """What the light condition's sun does to a view, as soft-edged elliptic patches: shadows
    (of goal posts, robots, the ball: long and thin or round; the sun's share of the light,
    `shadow_share`, taken away) and bright spots (`spot_gain` more light). Up to `patches` a
    row, each there with `chance` ([N, 1, 1, 1], 0 for rows left alone), two in three of them
    shadows. -> [N, 1, H, W] gains on linear light."""
    h, w = shape
    k = patches

    def draw(low: float, high: float) -> torch.Tensor:
        return low + (high - low) * torch.rand(n, k, 1, 1, generator=generator)

    on = (torch.rand(n, k, 1, 1, generator=generator) < chance.view(n, 1, 1, 1)).float()
    cx, cy = draw(-1.0, 1.0), draw(-1.0, 1.0)
    along, across = draw(0.1, 0.8), draw(0.03, 0.35)
    turn = draw(0.0, torch.pi)
    soft = draw(0.05, 0.4)
    shadow = (torch.rand(n, k, 1, 1, generator=generator) < 2 / 3).float()
    factor = shadow * (1 - draw(*shadow_share)) + (1 - shadow) * (1 + draw(*spot_gain))
    y = torch.linspace(-1, 1, h).view(1, 1, h, 1)
    x = torch.linspace(-1, 1, w).view(1, 1, 1, w) * (w / h)  # square pixels
    off_x, off_y = x - cx * (w / h), y - cy
    u = off_x * torch.cos(turn) + off_y * torch.sin(turn)
    v = -off_x * torch.sin(turn) + off_y * torch.cos(turn)
    radius = torch.sqrt((u / along) ** 2 + (v / across) ** 2)
    inside = torch.sigmoid((1 - radius) / soft)
    return torch.prod(1 + (factor - 1) * inside * on, dim=1, keepdim=True)
