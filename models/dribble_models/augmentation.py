"""What the trainer does to a batch's thumbnails before the network sees them: `Augment`, the
photometric and geometric jitter of `--augment`, `CameraAugment`, what the simulator's
camera conditions do to a thumbnail, at the thumbnail's scale (`--camera-augment`), and
`mirrored`, a row turned into the row of its mirror state (`--mirror`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from .camera_effects import CameraMotion, apply_camera_effects, light_patches
from .dataset import PHASES


@dataclass
class Augment:
    """Photometric and geometric jitter of training batches (off in the paper setup)."""

    brightness: float = 0.2  # gain in [1 - b, 1 + b]
    offset: float = 0.06  # added, in network units (pixel / 255)
    noise: float = 0.02  # Gaussian, network units
    shift: int = 4  # pixels of the top thumbnail (half for the bottom)

    def __call__(self, top: torch.Tensor, bottom: torch.Tensor, generator: torch.Generator):
        n = top.shape[0]
        gain = 1 + (torch.rand(n, 1, 1, 1, generator=generator) * 2 - 1) * self.brightness
        offset = (torch.rand(n, 1, 1, 1, generator=generator) * 2 - 1) * self.offset
        shifts = torch.randint(-self.shift, self.shift + 1, (n, 2), generator=generator)
        out = []
        for images, divisor in ((top, 1), (bottom, 2)):
            shifted = torch.empty_like(images)
            pad = self.shift // divisor
            padded = nn.functional.pad(images, (pad, pad, pad, pad), mode="replicate")
            h, w = images.shape[2:]
            for i in range(n):
                dy, dx = (int(s) // divisor for s in shifts[i])
                shifted[i] = padded[i, :, pad + dy : pad + dy + h, pad + dx : pad + dx + w]
            noisy = shifted * gain + offset + torch.randn(shifted.shape, generator=generator) * self.noise
            out.append(noisy.clamp(0.0, 1.0))
        return out[0], out[1]


#: The axes of a speed command (forward, left, turn: `contract.COMMAND_SCALE`) that a mirror
#: along the field's long axis negates.
MIRRORED_AXES = (1, 2)


#: The teacher's search phase (`expert::Phase::Search`).
SEARCH = PHASES.index("search")


def mirrorable(phase: np.ndarray) -> np.ndarray:
    """Which rows of one episode (its teacher's phases, in order) are their mirror state's
    rows too: all but the search before the episode's first sighting. There the teacher turns
    left by convention (`BallMemory::FIRST_SEARCH_TURN`: it has nothing to choose by), and a
    mirrored row would teach the opposite turn from images that look alike, a mean of no turn
    at all: a robot that never starts its search. Once it has seen the ball it searches toward
    the side it saw it last, which a mirror turns with it."""
    return np.logical_or.accumulate(np.asarray(phase) != SEARCH)


def mirrored(
    share: float,
    generator: torch.Generator,
    allowed: torch.Tensor,
    top: torch.Tensor,
    bottom: torch.Tensor,
    command: torch.Tensor,
    previous: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """A batch with `share` of its `allowed` rows (bool (N,); drawn from `generator`)
    replaced by their mirror state's: both thumbnails (N, 1, H, W) flipped left to right, the
    command's (N, 3) sideways and turn negated, and the last command's likewise where given.

    The field, its goals and lines, the walk and the teacher are the same in a mirror along the
    field's long axis: the target goal is the one on the ball's half either way, the teacher
    walks around the ball on the side of the ball-to-goal line it stands on and searches
    toward the side it last saw the ball, so the mirror of a recorded row is a row the teacher
    would have recorded in the mirror state (the cameras look straight ahead from the head's
    middle, so a mirrored image is what they would see there). Not so for a teacher that
    always walks around the ball one way (`--one-way-detour`, which the trainer refuses with
    `--mirror`), nor for the first search (`mirrorable`)."""
    chosen = (torch.rand(command.shape[0], generator=generator) < share) & allowed
    sign = torch.ones(command.shape[1])
    sign[list(MIRRORED_AXES)] = -1.0

    def images(batch: torch.Tensor) -> torch.Tensor:
        picked = chosen.to(batch.device).view(-1, *([1] * (batch.dim() - 1)))
        return torch.where(picked, batch.flip(-1), batch)

    def commands(batch: torch.Tensor) -> torch.Tensor:
        picked = chosen.to(batch.device).unsqueeze(1)
        return torch.where(picked, batch * sign.to(batch.device, batch.dtype), batch)

    return images(top), images(bottom), commands(command), None if previous is None else commands(previous)


@dataclass
class CameraAugment:
    """What the simulator's camera conditions do to a thumbnail (`apply_camera_effects`:
    exposure, vignetting, a softer or moving lens, contrast, sensor noise), drawn per row and
    applied to a share of the training rows where rendering them would cost an episode. Top
    and bottom share a row's exposure and contrast (one light, one processor) and the
    camera's turn (the same motion, at each thumbnail's own scale); each has its own noise
    and its own patches of light. The rest of what the light condition does (shadows cast
    where the geometry puts them), venues and robots change the scene and are rendered."""

    share: float = 0.5  # of the rows, augmented
    exposure_ev: float = 1.2  # uniform in +-
    contrast_low: float = 0.4  # contrast uniform in [low, 1]
    vignetting: float = 0.5  # corner loss uniform in [0, v]
    noise: float = 0.04  # standard deviation uniform in [0, n], network units
    blur_share: float = 0.3
    effect_chance: float = 0.5  # of each effect on an augmented row
    #: The camera's turn during the exposure (`CameraMotion`), on this share of the augmented
    #: rows: smear up to `smear_px` and rolling-shutter skew up to `skew_px` top-thumbnail
    #: pixels (0: none).
    motion_share: float = 0.0
    smear_px: float = 0.0
    skew_px: float = 0.0
    #: Soft shadows and bright spots (`light_patches`): each of up to three a view is there
    #: with this chance on an augmented row (0: none).
    patch_chance: float = 0.0

    #: `--camera-augment-strength`: the ranges above; ranges past the simulator's severity 5
    #: for contrast, exposure and noise, each effect on more of the rows (strong); or the
    #: standard ranges and the camera's turn (a directional smear and skew to past severity
    #: 5's) and patches of sunlight and shadow (motion-and-light).
    STRENGTHS = ("standard", "strong", "motion-and-light")

    @classmethod
    def of_strength(cls, share: float, strength: str) -> "CameraAugment":
        if strength == "strong":
            return cls(share=share, exposure_ev=1.6, contrast_low=0.25, vignetting=0.65, noise=0.06, blur_share=0.5, effect_chance=0.7)
        if strength == "motion-and-light":
            return cls(share=share, blur_share=0.15, motion_share=0.4, smear_px=8.0, skew_px=6.0, patch_chance=0.35)
        return cls(share=share)

    def __call__(self, top: torch.Tensor, bottom: torch.Tensor, generator: torch.Generator):
        n = top.shape[0]

        def draw(low: float, high: float) -> torch.Tensor:
            return low + (high - low) * torch.rand(n, 1, 1, 1, generator=generator)

        chosen = (torch.rand(n, 1, 1, 1, generator=generator) < self.share).float()
        on = lambda: (torch.rand(n, 1, 1, 1, generator=generator) < self.effect_chance).float() * chosen  # noqa: E731
        ev = draw(-self.exposure_ev, self.exposure_ev) * on()
        contrast = 1 + (draw(self.contrast_low, 1.0) - 1) * on()
        vignetting = draw(0.0, self.vignetting) * on()
        sigma = draw(0.0, self.noise) * on()
        blur = (torch.rand(n, 1, 1, 1, generator=generator) < self.blur_share).float() * chosen
        turn = self.turn(n, chosen, generator) if self.motion_share > 0 else None
        patch_chance = chosen * self.patch_chance
        out = []
        for images in (top, bottom):
            noise = torch.randn(images.shape, generator=generator) * sigma
            motion, shading = None, 1.0
            if turn is not None:
                scale = images.shape[-1] / top.shape[-1]
                motion = CameraMotion(turn[0] * scale, turn[1], turn[2] * scale)
            if self.patch_chance > 0:
                shading = light_patches(n, images.shape[-2:], generator, patch_chance)
            out.append(apply_camera_effects(images, ev, contrast, vignetting, blur, noise, shading, motion))
        return out[0], out[1]

    def turn(self, n: int, chosen: torch.Tensor, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Smear length, angle and skew (top-thumbnail pixels, radians) of the camera's turn,
        0 on the rows without one: mostly a turn (along x, within about 0.3 rad), a nod along
        y on a fifth of them."""
        moving = (torch.rand(n, generator=generator) < self.motion_share).float() * chosen.view(n)
        length = self.smear_px * torch.rand(n, generator=generator) * moving
        nod = (torch.rand(n, generator=generator) < 0.2).float()
        angle = 0.3 * torch.randn(n, generator=generator) + nod * torch.pi / 2
        sign = torch.where(torch.rand(n, generator=generator) < 0.5, -1.0, 1.0)
        skew = sign * self.skew_px * torch.rand(n, generator=generator) * moving * (1 - nod)
        return length, angle, skew
