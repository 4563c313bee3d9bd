"""dribble datasets as LeRobotDataset v3.0, and back (issue 51).

    scripts/lerobot export DATASET ROOT [--repo-id dribble/nao-dribble-observable]
    scripts/lerobot check DATASET ROOT      # LeRobot's own loader reads ROOT; rows compared
    scripts/lerobot import ROOT OUT         # a dribble dataset again (npz + dataset.json)

`scripts/lerobot` runs this module in an environment of its own (`~/.cache/dribble/
lerobot-venv`, LeRobot 0.4.4 pinned, with the torch it needs), so that the project's torch
is not held back by LeRobot's pins.

The dataset is written by LeRobot's own writer (`LeRobotDataset.create`, `add_frame`,
`save_episode`, `finalize`), one LeRobot frame per row of the dribble dataset (a command the
controller computed, at the cameras' 30 Hz):

| LeRobot feature | dribble row |
|---|---|
| `observation.images.top`, `observation.images.bottom` | the two thumbnails (160x120 and 80x60 luma), as lossless PNG images in the parquet files (three equal channels, as LeRobot's image features are RGB) |
| `action` | the teacher's command: forward, left, turn, normalised to [-1, 1] |
| `observation.state` | two zeros: the robot has no state beyond its images, but Diffusion asks for one (and LeRobot's loader hands a one-value feature over as a scalar, which ACT's state projection refuses: "mat1 and mat2 shapes cannot be multiplied (1x8 and 1x256)" on a batch of 8) |
| `teacher.phase` | the teacher's phase (0 search, 1 approach, 2 align, 3 dribble) |
| `episode.seed` | the episode's seed |
| `truth.robot_pose`, `truth.ball`, `truth.time_s` | ground truth beside the images (never a policy input) |
| `policy.command`, `policy.expert_executed` | DAgger rounds: the learned policy's own command and whether the teacher's replaced it |

Timestamps are `frame_index / 30`, as LeRobot checks them; the simulated time of each row
is `truth.time_s`. `meta/info.json`'s splits hold the dribble split (the last tenth of the
episodes for validation) and `meta/dribble.json` names the source (content hash, teacher,
conditions, seeds), so a model trained on the export can say what it learned from.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import sys
from pathlib import Path

import numpy as np

from .dataset import Dataset, Episode, load

FPS = 30
TASK = "Find the ball, walk to it, turn around it to face the goal and dribble it in."
PHASE_NAMES = ["search", "approach", "align", "dribble"]


def features(labelled: bool) -> dict:
    """The LeRobot features of a dribble dataset (`labelled`: a DAgger round's extra columns)."""
    image = lambda height, width: {"dtype": "image", "shape": (height, width, 3), "names": ["height", "width", "channels"]}  # noqa: E731
    found = {
        "observation.images.top": image(120, 160),
        "observation.images.bottom": image(60, 80),
        "observation.state": {"dtype": "float32", "shape": (2,), "names": ["zero_0", "zero_1"]},
        "action": {"dtype": "float32", "shape": (3,), "names": ["forward", "left", "turn"]},
        "teacher.phase": {"dtype": "int64", "shape": (1,), "names": ["phase"]},
        "episode.seed": {"dtype": "int64", "shape": (1,), "names": ["seed"]},
        "truth.robot_pose": {"dtype": "float32", "shape": (3,), "names": ["x_m", "y_m", "heading_rad"]},
        "truth.ball": {"dtype": "float32", "shape": (2,), "names": ["x_m", "y_m"]},
        "truth.time_s": {"dtype": "float64", "shape": (1,), "names": ["time_s"]},
    }
    if labelled:
        found["policy.command"] = {"dtype": "float32", "shape": (3,), "names": ["forward", "left", "turn"]}
        found["policy.expert_executed"] = {"dtype": "int64", "shape": (1,), "names": ["executed"]}
    return found


def labelled_arrays(directory: Path, seed: int, file: str) -> dict[str, np.ndarray]:
    """A DAgger round's extra columns of one episode (empty for demonstrations)."""
    with np.load(directory / file) as arrays:
        return {name: arrays[name] for name in ("policy_command", "expert_executed") if name in arrays.files}


def export(source: Path, root: Path, repo_id: str) -> dict:
    """Writes `source` (a dribble dataset) as a LeRobotDataset v3.0 under `root`; returns
    its `meta/info.json`."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = load(source)
    index = json.loads((source / "dataset.json").read_text())
    files = {int(entry["seed"]): entry["file"] for entry in index["episodes"]}
    labelled = "policy_command" in labelled_arrays(source, dataset.episodes[0].seed, files[dataset.episodes[0].seed])
    if root.exists():
        raise SystemExit(f"{root} exists: remove it or name another")
    out = LeRobotDataset.create(
        repo_id=repo_id, fps=FPS, features=features(labelled), root=root, robot_type="nao", use_videos=False
    )
    for episode in dataset.episodes:
        extra = labelled_arrays(source, episode.seed, files[episode.seed])
        for row in range(len(episode)):
            frame = {
                "observation.images.top": np.repeat(episode.top[row][:, :, None], 3, axis=2),
                "observation.images.bottom": np.repeat(episode.bottom[row][:, :, None], 3, axis=2),
                "observation.state": np.zeros(2, np.float32),
                "action": episode.command[row].astype(np.float32),
                "teacher.phase": np.array([episode.phase[row]], np.int64),
                "episode.seed": np.array([episode.seed], np.int64),
                "truth.robot_pose": np.asarray(episode.robot_pose[row], np.float32),
                "truth.ball": np.asarray(episode.ball[row], np.float32),
                "truth.time_s": np.array([episode.time_s[row]], np.float64),
                "task": TASK,
            }
            if labelled:
                frame["policy.command"] = extra["policy_command"][row].astype(np.float32)
                frame["policy.expert_executed"] = np.array([extra["expert_executed"][row]], np.int64)
            out.add_frame(frame)
        out.save_episode()
    out.finalize()
    held = (len(dataset.episodes) + 9) // 10
    info_path = root / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    first_held = len(dataset.episodes) - held
    info["splits"] = {"train": f"0:{first_held}", "validation": f"{first_held}:{len(dataset.episodes)}"}
    info_path.write_text(json.dumps(info, indent=4) + "\n")
    (root / "meta" / "dribble.json").write_text(
        json.dumps(
            {
                "source": str(source),
                "content_hash": dataset.content_hash,
                "teacher": dataset.teacher,
                "conditions": index.get("conditions", "clean"),
                "seeds": dataset.seeds(),
                "labelled": labelled,
                "phases": PHASE_NAMES,
            },
            indent=2,
        )
        + "\n"
    )
    return info


def read_back(root: Path, repo_id: str) -> list[tuple[Episode, dict[str, np.ndarray]]]:
    """The episodes LeRobot's own loader reads from `root`, as dribble rows (thumbnails from the
    images' first channel, bit for bit), with the labelled columns where there are any."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    loaded = LeRobotDataset(repo_id, root=root)
    table = loaded.hf_dataset.with_format(None)
    columns = {name: table[name] for name in table.column_names}
    episodes = []
    order = np.asarray(columns["episode_index"])
    for episode_index in sorted(set(order.tolist())):
        rows = np.flatnonzero(order == episode_index)
        images = lambda key: np.stack([np.asarray(image_of(columns[key][i]))[:, :, 0] for i in rows])  # noqa: E731
        column = lambda key, dtype: np.asarray([columns[key][i] for i in rows], dtype)  # noqa: E731
        episode = Episode(
            seed=int(column("episode.seed", np.int64)[0].item()),
            top=images("observation.images.top").astype(np.uint8),
            bottom=images("observation.images.bottom").astype(np.uint8),
            command=column("action", np.float32),
            phase=column("teacher.phase", np.int64).reshape(-1).astype(np.uint8),
            robot_pose=column("truth.robot_pose", np.float32),
            ball=column("truth.ball", np.float32),
            time_s=column("truth.time_s", np.float64).reshape(-1),
        )
        extra = {}
        if "policy.command" in columns:
            extra["policy_command"] = column("policy.command", np.float32)
            extra["expert_executed"] = column("policy.expert_executed", np.int64).reshape(-1).astype(np.uint8)
        episodes.append((episode, extra))
    return episodes


def image_of(value):
    """A stored image as LeRobot's table gives it without a format: a PIL image, or the PNG
    bytes it was written as."""
    if isinstance(value, dict) and value.get("bytes") is not None:
        from PIL import Image

        return Image.open(io.BytesIO(value["bytes"]))
    return value


def differences(source: Dataset, extras: dict[int, dict], back: list[tuple[Episode, dict]]) -> list[str]:
    """Where the rows read back differ from the source's (empty: the same rows)."""
    found = []
    if [e.seed for e in source.episodes] != [e.seed for e, _ in back]:
        return [f"episodes differ: {source.seeds()} against {[e.seed for e, _ in back]}"]
    for original, (copy, extra) in zip(source.episodes, back):
        for name in ("top", "bottom", "command", "phase", "robot_pose", "ball", "time_s"):
            a, b = getattr(original, name), getattr(copy, name)
            if a.shape != b.shape or not np.array_equal(a, b):
                found.append(f"episode {original.seed}: {name} differs")
        for name, values in extras.get(original.seed, {}).items():
            if name not in extra or not np.array_equal(values, extra[name]):
                found.append(f"episode {original.seed}: {name} differs")
    return found


def write_dribble(episodes: list[tuple[Episode, dict]], out: Path, teacher: str) -> str:
    """A dribble dataset directory (npz per episode, dataset.json with hashes) from rows;
    returns its content hash."""
    from .dataset import content_hash

    out.mkdir(parents=True, exist_ok=False)
    entries = []
    for episode, extra in episodes:
        file = f"episode_{episode.seed:05d}.npz"
        buffer = io.BytesIO()
        np.savez(
            buffer,
            top=episode.top,
            bottom=episode.bottom,
            command=episode.command,
            robot_pose=episode.robot_pose,
            ball=episode.ball,
            time_s=episode.time_s,
            phase=episode.phase,
            **extra,
        )
        data = buffer.getvalue()
        (out / file).write_bytes(data)
        entries.append({"seed": episode.seed, "file": file, "rows": len(episode), "sha256": hashlib.sha256(data).hexdigest()})
    digest = content_hash(entries)
    index = {"format": 1, "teacher": teacher, "episodes": entries, "content_hash": digest, "imported_from": "LeRobotDataset v3.0"}
    (out / "dataset.json").write_text(json.dumps(index, indent=2) + "\n")
    return digest


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/lerobot", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    export_parser = commands.add_parser("export", help="write a dribble dataset as a LeRobotDataset v3.0")
    export_parser.add_argument("dataset", type=Path)
    export_parser.add_argument("root", type=Path, help="the LeRobot dataset's directory (must not exist)")
    check_parser = commands.add_parser("check", help="read ROOT with LeRobot's loader and compare its rows with DATASET's")
    check_parser.add_argument("dataset", type=Path)
    check_parser.add_argument("root", type=Path)
    import_parser = commands.add_parser("import", help="write a LeRobot export back as a dribble dataset")
    import_parser.add_argument("root", type=Path)
    import_parser.add_argument("out", type=Path)
    for sub in (export_parser, check_parser, import_parser):
        sub.add_argument("--repo-id", default="dribble/nao-dribble", help="the LeRobot repository id (nothing is uploaded)")
    args = parser.parse_args(argv)
    if args.command == "export":
        info = export(args.dataset, args.root, args.repo_id)
        print(json.dumps(info, indent=2))
        return 0
    if args.command == "check":
        source = load(args.dataset)
        index = json.loads((args.dataset / "dataset.json").read_text())
        extras = {int(e["seed"]): labelled_arrays(args.dataset, int(e["seed"]), e["file"]) for e in index["episodes"]}
        back = read_back(args.root, args.repo_id)
        found = differences(source, extras, back)
        for line in found:
            print(line, file=sys.stderr)
        rows = sum(len(e) for e, _ in back)
        print(f"LeRobot read {len(back)} episodes, {rows} frames from {args.root}: " + ("the same rows" if not found else f"{len(found)} differences"))
        return 1 if found else 0
    back = read_back(args.root, args.repo_id)
    teacher = json.loads((args.root / "meta" / "dribble.json").read_text()).get("teacher", "paper")
    digest = write_dribble(back, args.out, teacher)
    print(f"wrote {args.out}: {len(back)} episodes, content hash {digest}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
