"""The simulator as a Gymnasium environment: ``dribble/NaoDribble-v0``.

    import gymnasium as gym
    import dribble_models.gym_env  # registers the environment
    env = gym.make("dribble/NaoDribble-v0")
    observation, info = env.reset(seed=10000)   # the paper's first test episode

The episodes are the project's: ``reset(seed=S)`` places robot and ball as episode seed S
does in ``dribble record``/``eval`` (the test seeds are 10000..10019, the training seeds
0..99); ``reset()`` without a seed draws one from the environment's generator, from
100000 up, outside every range the project names.

The environment runs ``dribble gym-server`` (src/commands/gym_server.rs) as a child process
and talks to it over pipes: the same simulator, renderer and controller code that
``dribble eval`` runs. An **observation** comes whenever the robot's controller would
compute a command (both cameras have a new frame, about 30 times a simulated second): the
two thumbnails the policy sees, made by the controller's own code, ``{"top": uint8 (120,
160), "bottom": uint8 (60, 80)}``. An **action** is the normalised speed command
``[forward, left, turn]`` in [-1, 1] (1 = 0.25 m/s, 0.15 m/s, 1 rad/s); the controller
clamps it and turns a non-finite one into a stop, as on the robot, and the robot walks on it
until the next observation.

``terminated`` when the ball is in the goal it attacks or leaves the field; ``truncated`` at
the time limit (90 simulated seconds, the paper's). **Reward**: 1 for a goal, else 0.
Optional shaping, off by default (``shaping=w``): each step adds ``w`` times the decrease of
the ball's distance to the attacked goal's centre, in metres (a potential-based shaping, Ng,
Harada and Russell 1999, which leaves the best policy unchanged).

``info`` holds the ground truth the policy does not see: ``time_s``, ``robot`` (x, y,
heading), ``ball``, ``target_side``, ``goal_centre``, ``seed``, and the teacher's command
and phase for that state (``expert_command``, ``expert_phase``; the teacher is
``expert="paper"``, ``"observable"``, ``"orbit"``, ``"detector"`` or ``"detector-one-way"``, asked exactly where DAgger's labels are). The last
step's ``info`` adds the ``outcome``, ``duration_s``, ``walked_m``, ``computed_commands``,
``first_sighting_s`` and the 10 Hz ``trajectory`` that ``dribble eval --trajectories``
writes.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

TOP_SHAPE = (120, 160)
BOTTOM_SHAPE = (60, 80)
FIRST_UNNAMED_SEED = 100_000
ENV_ID = "dribble/NaoDribble-v0"


def find_dribble() -> str:
    """The ``dribble`` binary: $DRIBBLE_BIN, else the release build the scripts make, else PATH."""
    candidates = [os.environ.get("DRIBBLE_BIN")]
    target = os.environ.get("CARGO_TARGET_DIR", str(Path.home() / ".cache/dribble/target"))
    candidates.append(str(Path(target) / "release/dribble"))
    candidates.append(str(Path(__file__).resolve().parents[2] / "target/release/dribble"))
    for candidate in candidates:
        if candidate and Path(candidate).is_file() and os.access(candidate, os.X_OK):
            return candidate
    found = shutil.which("dribble")
    if found:
        return found
    raise FileNotFoundError(
        "no dribble binary: build it (cargo build --release) or set DRIBBLE_BIN"
    )


class ServerError(RuntimeError):
    """The gym server refused a request, or stopped."""


class NaoDribbleEnv(gym.Env):
    """One Nao, one ball, one goal to score in, seen through the robot's two cameras."""

    metadata = {"render_modes": []}

    def __init__(
        self,
        expert: str = "paper",
        time_limit_s: float = 90.0,
        shaping: float = 0.0,
        binary: str | None = None,
        condition: str = "clean",
        camera_samples: int = 4,
    ):
        if expert not in ("paper", "observable", "orbit", "detector", "detector-one-way"):
            raise ValueError(f"expert is 'paper', 'observable', 'orbit', 'detector' or 'detector-one-way', not {expert!r}")
        if not (time_limit_s > 0 and np.isfinite(time_limit_s)):
            raise ValueError(f"time_limit_s must be positive and finite, not {time_limit_s}")
        if camera_samples not in (4, 1):
            raise ValueError(f"camera_samples is 4 (every shipped result's frames) or 1, not {camera_samples!r}")
        self.observation_space = spaces.Dict(
            {
                "top": spaces.Box(0, 255, TOP_SHAPE, np.uint8),
                "bottom": spaces.Box(0, 255, BOTTOM_SHAPE, np.uint8),
            }
        )
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self.expert = expert
        self.time_limit_s = float(time_limit_s)
        self.shaping = float(shaping)
        # What the cameras see the episodes under (`dribble eval --help`: clean, NAME:SEVERITY[,...]
        # or randomized); the server refuses a text it cannot read.
        self.condition = str(condition)
        # Samples a pixel of the cameras' images: 4, or 1 for about two fifths of the CPU a
        # clean step costs (frames differ along edges; docs/src/design/performance.md).
        self.camera_samples = int(camera_samples)
        self._binary = binary
        self._server: subprocess.Popen | None = None
        self._log = None
        self._in_episode = False
        self._ball_distance = 0.0

    # -- the server ---------------------------------------------------------------------

    def _start(self) -> subprocess.Popen:
        if self._server is not None and self._server.poll() is None:
            return self._server
        command = [
            self._binary or find_dribble(),
            "gym-server",
            "--teacher",
            self.expert,
            "--time-limit",
            repr(self.time_limit_s),
            "--condition",
            self.condition,
            "--camera-samples",
            str(self.camera_samples),
        ]
        # Its log goes to a file: a pipe nobody reads would fill and stall it.
        self._log = tempfile.TemporaryFile()
        self._server = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log
        )
        return self._server

    def _read(self, count: int) -> bytes:
        assert self._server is not None and self._server.stdout is not None
        data = self._server.stdout.read(count)
        if data is None or len(data) != count:
            error = b""
            if self._log is not None:
                try:
                    self._server.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    pass
                self._log.seek(0)
                error = self._log.read()
            raise ServerError(
                f"dribble gym-server stopped (exit {self._server.poll()}): "
                f"{error.decode(errors='replace').strip()[-2000:]}"
            )
        return data

    def _ask(self, request: bytes) -> tuple[str, dict[str, np.ndarray] | None, dict]:
        server = self._start()
        assert server.stdin is not None
        try:
            server.stdin.write(request)
            server.stdin.flush()
        except BrokenPipeError:
            self._read(1)  # raises with the server's last words
        tag = self._read(1).decode()
        observation = None
        if tag in ("O", "E"):
            top = np.frombuffer(self._read(TOP_SHAPE[0] * TOP_SHAPE[1]), np.uint8)
            bottom = np.frombuffer(self._read(BOTTOM_SHAPE[0] * BOTTOM_SHAPE[1]), np.uint8)
            observation = {
                "top": top.reshape(TOP_SHAPE).copy(),
                "bottom": bottom.reshape(BOTTOM_SHAPE).copy(),
            }
        (length,) = struct.unpack("<I", self._read(4))
        text = self._read(length).decode()
        if tag == "X":
            raise ServerError(text)
        if tag not in ("O", "E"):
            raise ServerError(f"unexpected answer {tag!r} from dribble gym-server")
        info = json.loads(text)
        for key in ("robot", "ball", "goal_centre", "expert_command"):
            if key in info:
                info[key] = np.asarray(info[key], dtype=np.float64)
        return tag, observation, info

    def _distance_to_goal(self, info: dict) -> float:
        return float(np.linalg.norm(info["ball"] - info["goal_centre"]))

    # -- Gymnasium ----------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Starts the episode ``seed`` (or ``options["episode"]``; else one drawn at random)."""
        super().reset(seed=seed)
        if options and "episode" in options:
            episode = int(options["episode"])
        elif seed is not None:
            episode = int(seed)
        else:
            episode = int(self.np_random.integers(FIRST_UNNAMED_SEED, 2**63 - 1))
        if not 0 <= episode < 2**64:
            raise ValueError(f"an episode seed is an unsigned 64-bit number, not {episode}")
        tag, observation, info = self._ask(b"R" + struct.pack("<Q", episode))
        if tag != "O":
            raise ServerError(f"episode {episode} ended before its first observation: {info}")
        self._in_episode = True
        self._ball_distance = self._distance_to_goal(info)
        return observation, info

    def step(self, action):
        if not self._in_episode:
            raise RuntimeError("step() after the episode ended: call reset() first")
        action = np.asarray(action, dtype=np.float32).reshape(3)
        tag, observation, info = self._ask(b"S" + struct.pack("<3f", *action.tolist()))
        reward = 0.0
        if self.shaping:
            distance = self._distance_to_goal(info)
            reward += self.shaping * (self._ball_distance - distance)
            self._ball_distance = distance
        terminated = truncated = False
        if tag == "E":
            self._in_episode = False
            outcome = info["outcome"]
            if outcome == "goal":
                reward += 1.0
            terminated = outcome in ("goal", "ball_out")
            truncated = outcome == "time_limit"
            if not (terminated or truncated):
                raise ServerError(f"the episode ended as {outcome}")
        return observation, reward, terminated, truncated, info

    def close(self):
        server, self._server = self._server, None
        if server is None:
            return
        try:
            if server.poll() is None and server.stdin is not None:
                server.stdin.write(b"Q")
                server.stdin.close()
            server.wait(timeout=10)
        except (BrokenPipeError, subprocess.TimeoutExpired):
            server.kill()
            server.wait()
        for stream in (server.stdout, self._log):
            if stream is not None:
                stream.close()
        self._log = None
        super().close()


gym.register(id=ENV_ID, entry_point=NaoDribbleEnv)
