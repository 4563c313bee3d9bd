"""What policies answer on the frames of a closed loop, beside the teacher's command there:
the tool for a miss such as "stood at the ball" (issue 48).

    dribble eval --driver models/policy/A/policy.toml --episodes 20016..20017 \\
        --condition unseen-venue:3 --mcap DIR --mcap-camera-hz 1
    python -m dribble_models.stall_frames DIR/episode_20016.mcap --from 55 --to 65 \\
        models/policy/A models/policy/B

From an episode's MCAP file (`dribble eval --mcap`): the thumbnails the driving policy saw
between two simulated times, and the robot's and the ball's poses there. Each named CNN
(float, one network; a two-hypothesis CNN shows both hypotheses and which its choice takes)
runs on those thumbnails as the controller feeds them (`contract.network_input`, the
manifest's normalisation); a CNN that reads the last command sent (`[inputs] previous`) is fed
the command the driving policy had sent before each frame, from the file's `/motion/command`,
so that the driving policy's own float model answers what the robot answered, or with
`--previous F,L,T` that one command on every frame (what would it answer had it been turning?).
Beside them
stand the commands the driving policy sent on those frames, and stands the detector teacher's approach command
at the window's middle pose (`OneWayDetour.command`, the two-way detour) for the target
goal and for the other one: where those two differ and the images cannot tell the goals
apart, a regression answers their mean. The episode's seed must be a training, validation
or selection seed: failures are studied there, never on test or fresh seeds.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import contract
from .networks import CNN, CameraFeatures, Filters, ModalCNN, PreviousCommandCNN, set_standardise
from .one_way_detour import OneWayDetour
from .seed_ranges import reserved_among
from .shipped_weights import ShippedWeightsError, load_shipped_weights, shipped_initializers


class StallFramesError(ValueError):
    """The file or the window holds nothing to study, or the seed is reserved."""


@dataclass
class Window:
    """The thumbnails of a time window and the poses at its middle (field frame)."""

    seed: int
    top: np.ndarray  # u8 [N, 120, 160]
    bottom: np.ndarray  # u8 [N, 60, 80]
    robot_pose: np.ndarray  # x m, y m, heading rad
    ball: np.ndarray  # x m, y m
    first_ball: np.ndarray  # where the ball lay at the start: it names the target goal
    # The command the driving policy had sent last before each frame (normalised; a stop
    # before its first), what a network reading `[inputs] previous` was fed: f32 [N, 3].
    previous: np.ndarray | None = None
    # The command it sent next after each frame, computed from it: f32 [N, 3].
    sent: np.ndarray | None = None


def _decoder(schema):
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def _yaw(q) -> float:
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y**2 + q.z**2))


def read_window(path: Path, start_s: float, end_s: float) -> Window:
    """The thumbnails between `start_s` and `end_s` of the episode in `path` (seconds from its
    first thumbnail) and the poses nearest the window's middle."""
    from mcap.reader import make_reader

    wanted = {"/policy/thumbnail/top", "/policy/thumbnail/bottom", "/robot/pose", "/ball/pose"}
    decoders: dict[str, object] = {}
    rows: dict[str, list] = {topic: [] for topic in wanted}
    commands: list[tuple[int, np.ndarray]] = []
    try:
        with open(path, "rb") as stream:
            for schema, channel, message in make_reader(stream).iter_messages(topics=[*wanted, COMMAND_TOPIC], log_time_order=True):
                if channel.topic == COMMAND_TOPIC:
                    commands.append((message.log_time, command_of(message.data)))
                    continue
                if channel.topic not in decoders:
                    decoders[channel.topic] = _decoder(schema)
                rows[channel.topic].append((message.log_time, decoders[channel.topic].FromString(message.data)))
    except OSError as error:
        raise StallFramesError(f"{path}: {error}") from error
    if not rows["/policy/thumbnail/top"] or not rows["/ball/pose"]:
        raise StallFramesError(f"{path}: no thumbnails or poses (an MCAP file of `dribble eval --mcap`?)")
    seed = int(path.stem.rsplit("_", 1)[-1]) if path.stem.startswith("episode_") else -1
    start = rows["/policy/thumbnail/top"][0][0]
    inside = lambda t: start_s <= (t - start) / 1e9 <= end_s  # noqa: E731
    # The two thumbnails of a frame, in order (the pair a tick feeds the network).
    pairs = [(t, a, b) for (t, a), (_, b) in zip(rows["/policy/thumbnail/top"], rows["/policy/thumbnail/bottom"]) if inside(t)]
    if not pairs:
        raise StallFramesError(f"{path}: no thumbnails between {start_s} and {end_s} s")
    top = [np.frombuffer(a.data, np.uint8).reshape(contract.TOP_SHAPE) for _, a, _ in pairs]
    bottom = [np.frombuffer(b.data, np.uint8).reshape(contract.BOTTOM_SHAPE) for _, _, b in pairs]
    middle = start + (start_s + end_s) / 2 * 1e9

    def nearest(topic: str):
        return min(rows[topic], key=lambda row: abs(row[0] - middle))[1].pose

    robot, ball = nearest("/robot/pose"), nearest("/ball/pose")
    first_ball = rows["/ball/pose"][0][1].pose.position
    previous, sent = commands_around([t for t, _, _ in pairs], commands)
    return Window(
        seed,
        np.stack(top),
        np.stack(bottom),
        np.array([robot.position.x, robot.position.y, _yaw(robot.orientation)]),
        np.array([ball.position.x, ball.position.y]),
        np.array([first_ball.x, first_ball.y]),
        previous,
        sent,
    )


COMMAND_TOPIC = "/motion/command"


def command_of(data: bytes) -> np.ndarray:
    """A `/motion/command` message (JSON: forward, left, turn normalised) as f32 [3]."""
    message = json.loads(data)
    return np.array([message["forward"], message["left"], message["turn"]], np.float32)


def commands_around(times: list[int], commands: list[tuple[int, np.ndarray]]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """For each frame time, the last command published before it (a stop before the first)
    and the first at or after it (the one computed from it; the last known at the end): None
    where the file holds no commands."""
    if not commands:
        return None, None
    stamps = np.array([t for t, _ in commands])
    values = np.stack([c for _, c in commands])
    before = np.searchsorted(stamps, times, side="left") - 1
    previous = np.where(before[:, None] >= 0, values[np.maximum(before, 0)], 0.0).astype(np.float32)
    after = np.minimum(np.searchsorted(stamps, times, side="left"), len(stamps) - 1)
    return previous, values[after]


def refuse_reserved(seed: int) -> None:
    """Refuses an episode of the test or fresh seeds (reporting only); selection seeds are
    where failures are studied."""
    for name in set(reserved_among([seed])) - {"selection"}:
        raise StallFramesError(f"seed {seed} is one of the {name} seeds: failures are studied on selection seeds")


def network_of(model: Path) -> tuple[torch.nn.Module, bool]:
    """The float CNN at `model` (one output, several hypotheses, or reading the last command;
    any filter counts) and whether its manifest standardises the thumbnails."""
    try:
        manifest_path, initializers = shipped_initializers(model, "cnn")
        filters = Filters(*(int(initializers[f"features.{branch}.{layer}.weight"].shape[0]) for branch in ("top", "bottom") for layer in (0, 3)))
    except (ShippedWeightsError, KeyError) as error:
        raise StallFramesError(f"{model}: not a one-network float CNN ({error})") from error
    if "choice.weight" in initializers:
        network = ModalCNN(int(initializers["choice.weight"].shape[0]), filters)
    elif "hidden.weight" in initializers:
        network = PreviousCommandCNN(CameraFeatures(filters))
    else:
        network = CNN(filters)
    try:
        load_shipped_weights(network, model, "cnn")
    except ShippedWeightsError as error:
        raise StallFramesError(str(error)) from error
    set_standardise(network, False)  # the input below is made as the controller makes it
    standardise = bool(tomllib.loads(manifest_path.read_text())["normalisation"].get("standardise", False))
    return network.eval(), standardise


def answers(model: Path, window: Window) -> dict:
    """The commands `model` sends on the window's thumbnails: mean, least and most; for a
    two-hypothesis CNN each hypothesis's mean and how often the choice takes it."""
    network, standardise = network_of(model)
    scale = contract.INPUT_SCALE
    top = torch.from_numpy(contract.network_input(window.top[:, None], standardise, scale))
    bottom = torch.from_numpy(contract.network_input(window.bottom[:, None], standardise, scale))
    inputs = (top, bottom)
    if isinstance(network, PreviousCommandCNN):
        if window.previous is None:
            raise StallFramesError(f"{model.name} reads the last command sent; the file holds no {COMMAND_TOPIC}")
        inputs = (top, bottom, torch.from_numpy(window.previous))
    with torch.no_grad():
        sent = network(*inputs).numpy()
        out = {"mean": sent.mean(0), "least": sent.min(0), "most": sent.max(0)}
        if isinstance(network, ModalCNN):
            hypotheses, logits = network.forward_all(top, bottom)
            chosen = logits.argmax(dim=1).numpy()
            out["hypotheses"] = [(hypotheses[:, k].numpy().mean(0), float((chosen == k).mean())) for k in range(network.modes)]
    return out


def teacher_commands(window: Window) -> tuple[np.ndarray, np.ndarray, bool]:
    """The detector teacher's approach at the window's middle for the target goal and for the
    other one, and whether it is the detour around the ball."""
    rule = OneWayDetour()
    side = 1.0 if window.first_ball[0] >= 0.0 else -1.0
    target, detour = rule.command(window.robot_pose, window.ball, side, one_way=False)
    other, _ = rule.command(window.robot_pose, window.ball, -side, one_way=False)
    return target, other, detour


def previous_command(text: str) -> np.ndarray:
    """`--previous F,L,T`: three normalised components within [-1, 1]."""
    try:
        values = np.array([float(part) for part in text.split(",")], np.float32)
    except ValueError:
        values = np.zeros(0, np.float32)
    if values.shape != (3,) or not np.all(np.abs(values) <= 1.0):
        raise argparse.ArgumentTypeError(f"a command is three normalised values within [-1, 1] such as 0,0,0.5, not {text!r}")
    return values


def fmt(command: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:+.2f}" for v in command) + ")"


def report(window: Window, models: list[Path]) -> str:
    target, other, detour = teacher_commands(window)
    pose, ball = window.robot_pose, window.ball
    lines = [
        f"seed {window.seed}, {len(window.top)} frames; robot ({pose[0]:.2f}, {pose[1]:.2f}) m heading "
        f"{math.degrees(pose[2]):.0f} deg, ball ({ball[0]:.2f}, {ball[1]:.2f}) m, {np.linalg.norm(pose[:2] - ball):.2f} m away",
        f"teacher (forward, left, turn): {fmt(target)} toward the target goal{' (detour)' if detour else ''}, "
        f"{fmt(other)} were the other goal the target",
    ]
    if window.sent is not None:
        lines.append(f"the driving policy sent {fmt(window.sent.mean(0))} on average on these frames (least {fmt(window.sent.min(0))}, most {fmt(window.sent.max(0))})")
    for model in models:
        out = answers(model, window)
        lines.append(f"{model.name}: sends {fmt(out['mean'])} on average (least {fmt(out['least'])}, most {fmt(out['most'])})")
        for k, (mean, share) in enumerate(out.get("hypotheses", [])):
            lines.append(f"  hypothesis {k}: {fmt(mean)}, chosen on {share:.0%} of the frames")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mcap", type=Path, help="an episode's MCAP file (dribble eval --mcap DIR: DIR/episode_SEED.mcap)")
    parser.add_argument("models", type=Path, nargs="+", help="float CNNs to run on its frames (models/policy/NAME)")
    parser.add_argument("--from", dest="start", type=float, required=True, help="the window's start, simulated seconds")
    parser.add_argument("--to", dest="end", type=float, required=True, help="the window's end, simulated seconds")
    parser.add_argument(
        "--previous",
        type=previous_command,
        metavar="F,L,T",
        help="feed a CNN that reads the last command sent this one (normalised forward, left, turn) on every frame, not the one the driving policy had sent",
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    try:
        window = read_window(args.mcap, args.start, args.end)
        refuse_reserved(window.seed)
        if args.previous is not None:
            window.previous = np.tile(args.previous, (len(window.top), 1))
        print(report(window, args.models))
    except StallFramesError as error:
        print(f"stall_frames: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
