"""How much a camera effect moves a policy's commands, offline: the command error of CNN
policies on held-out dataset rows whose thumbnails were changed the way a camera condition
changes them (issue 48).

    python -m dribble_models.thumbnail_effects --dataset ~/.cache/dribble/data/randomized-detector \\
        --seeds 55,56,57 models/policy/cnn-dagger2-observable models/policy/cnn-conditions

A closed loop under a rendered condition costs minutes per episode on two cores; this costs
seconds per policy, so it ranks training recipes before closed loops on the selection seeds
choose among them. It is a proxy and says so: the effects here are painted on the u8
thumbnails (the simulator renders them at the cameras' resolution before YUYV packing), and
the error is the teacher's label against the policy's command on the teacher's own states,
not what happens when the policy drives. Only point effects are close to the rendered ones
(contrast and exposure act on each pixel; sensor noise averaged over a thumbnail pixel's 4x4
camera pixels has a quarter of its spread; the lens is approximated by a 3x3 box at the
thumbnail's scale, the camera's turn by a horizontal smear and rolling-shutter skew of the
pixels the simulator's motion blur moves the image by, `CameraMotion`). Rows must come from
training or validation seeds, never from selection, test or fresh seeds
(`seed_ranges.refuse_reserved`): the numbers here inform choices.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import dataset, seed_ranges
from .camera_effects import CameraMotion, apply_camera_effects
from .contract import TOP_SHAPE
from .gym_equivalence import OnnxPolicy
from .command_metric import row_errors

TOP_WIDTH = TOP_SHAPE[1]

@dataclass(frozen=True)
class ThumbnailEffect:
    """One named change of a thumbnail's display values in [0, 1]."""

    name: str
    exposure_ev: float = 0.0
    contrast: float = 1.0
    noise: float = 0.0  # standard deviation at the thumbnail's scale, display units
    blur: bool = False
    vignetting: float = 0.0
    #: A turn during the exposure, in top-thumbnail pixels (the bottom camera's thumbnail,
    #: half as wide, moves half as far): smear along x and rolling-shutter skew.
    smear_px: float = 0.0
    skew_px: float = 0.0

    def apply(self, thumbnails: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """u8 [N, H, W] -> u8 [N, H, W], as `apply_camera_effects` changes them (the noise
        drawn from `rng`)."""
        display = torch.from_numpy(thumbnails.astype(np.float32) / 255.0)[:, None]
        noise = torch.from_numpy(rng.normal(0.0, self.noise, display.shape).astype(np.float32)) if self.noise else 0.0
        motion = None
        if self.smear_px or self.skew_px:
            n, scale = display.shape[0], display.shape[-1] / TOP_WIDTH
            motion = CameraMotion(torch.full((n,), self.smear_px * scale), torch.zeros(n), torch.full((n,), self.skew_px * scale))
        shown = apply_camera_effects(display, self.exposure_ev, self.contrast, self.vignetting, float(self.blur), noise, motion=motion)
        return np.clip(np.rint(shown[:, 0].numpy() * 255.0), 0, 255).astype(np.uint8)


#: Severity 3 of the point and lens conditions as the simulator draws them
#: (sim-harness/src/conditions/camera.rs), at the thumbnail's scale.
SEVERITY_3 = (
    ThumbnailEffect("clean"),
    ThumbnailEffect("exposure:3 (-0.7 EV)", exposure_ev=-0.7),
    ThumbnailEffect("exposure:3 (+0.7 EV)", exposure_ev=0.7),
    ThumbnailEffect("contrast:3 (0.5)", contrast=0.5),
    ThumbnailEffect("contrast:5 (0.3)", contrast=0.3),
    ThumbnailEffect("noise:3 (20/255 raw)", noise=20.0 / 255.0 / 4.0),
    ThumbnailEffect("noise:5 (45/255 raw)", noise=45.0 / 255.0 / 4.0),
    ThumbnailEffect("blur (3x3)", blur=True),
    ThumbnailEffect("lens:3 (vignetting 0.35, blur)", vignetting=0.35, blur=True),
    ThumbnailEffect("turn:3 (4 px smear, 4 px skew)", smear_px=4.0, skew_px=4.0),
    ThumbnailEffect("turn:5 (7 px smear, 5 px skew)", smear_px=7.0, skew_px=5.0),
)


def errors_under_effects(policies: list[Path], episodes: list[dataset.Episode], effects=SEVERITY_3, seed: int = 0) -> dict:
    """{policy name: {effect name: mean command error}} on every row of `episodes`."""
    top = np.concatenate([e.top for e in episodes])
    bottom = np.concatenate([e.bottom for e in episodes])
    expert = np.concatenate([e.command for e in episodes])
    changed = {}
    for index, effect in enumerate(effects):
        rng = np.random.default_rng([seed, index])
        changed[effect.name] = (effect.apply(top, rng), effect.apply(bottom, rng))
    table = {}
    for policy in policies:
        # The Gymnasium comparison's onnxruntime runner: one row at a time, as the robot runs it.
        network = OnnxPolicy(policy / "policy.toml")
        table[policy.name] = {
            name: float(row_errors(np.array([network({"top": a, "bottom": b}) for a, b in zip(t, bs)]), expert).mean())
            for name, (t, bs) in changed.items()
        }
    return table


def markdown(table: dict, rows: int, seeds: list[int]) -> str:
    effects = list(next(iter(table.values())))
    lines = [
        f"Command error on {rows} rows of seeds {', '.join(map(str, seeds))} (thumbnails changed offline):",
        "",
        "| policy | " + " | ".join(effects) + " |",
        "|---|" + "---:|" * len(effects),
    ]
    for policy, errors in table.items():
        lines.append(f"| {policy} | " + " | ".join(f"{errors[e]:.3f}" for e in effects) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("policies", nargs="+", type=Path, help="shipped one-network CNN model directories")
    parser.add_argument("--dataset", type=Path, required=True, help="a `dribble record` directory")
    parser.add_argument("--seeds", required=True, help="comma-separated episode seeds (training or validation seeds only)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the noise draws")
    parser.add_argument("--json", type=Path, help="also write the table here")
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",") if s]
    try:
        seed_ranges.refuse_reserved(seeds, "--seeds", use="offline look (it informs choices)")
        data = dataset.load(args.dataset, require_seeds=seeds)
    except (ValueError, dataset.DatasetError) as error:
        print(f"thumbnail_effects: {error}", file=sys.stderr)
        return 2
    episodes = data.subset(seeds)
    try:
        table = errors_under_effects(args.policies, episodes, seed=args.seed)
    except (OSError, ValueError) as error:
        print(f"thumbnail_effects: {error}", file=sys.stderr)
        return 2
    rows = sum(len(e) for e in episodes)
    print(markdown(table, rows, seeds))
    if args.json:
        args.json.write_text(json.dumps({"dataset": data.content_hash, "seeds": seeds, "rows": rows, "errors": table}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
