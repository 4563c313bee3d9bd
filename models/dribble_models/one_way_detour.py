"""The teacher's detour around the ball, relabelled to go one way (trainer `--one-way-detour`).

The scripted teacher (`sim-harness/src/expert.rs`, `Expert::approach`) walks around the ball
when it stands on the goal side of it or level with it, on the side of the ball-to-goal line
it stands on. Which goal is the target is ground truth (the one on the ball's half), so two
states whose images are each other's mirror picture, a robot facing a plain wall with the ball
in front of its feet, one with the target goal to its left and one with it to its right, get
opposite sideways commands. A CNN trained on both regresses to their mean and stands still
beside the ball for the rest of the episode: the closed-loop failure of the standardised
conditions students on selection seeds 20009, 20011 and 20013 (docs/src/history/
conditions-students.md), whose outputs there were 0.00 on all three axes while the shipped
model stepped sideways.

`OneWayDetour.relabelled` gives those rows the teacher's own walk (`walk_towards`) toward a
point on the detour circle a sixth of a turn clockwise, seen from above, of the robot: around
the ball always the same way, a direction the images explain. It loses only which side of
the ball-to-goal line is shorter, which the robot cannot see there. Where the robot has come
round behind the ball the recorded labels stand. The `detector-one-way` teacher
(`Teacher::DetectorOneWay`) drives and labels the same way; this relabelling lets the
recorded detector data and rounds serve it without recording them again. The rows are found
from the recorded ground truth (robot pose, ball, the target goal from the ball's first
position): a row is relabelled only where the teacher's two-way detour, recomputed here,
gives the command it recorded (to 1e-3), so rows whose ball was remembered rather than seen,
rows of another phase and rows the one-way teacher recorded itself are left as they are.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .dataset import PHASES, Episode
from .eval_summary import GOAL_X_M

#: The phase code of the teacher's approach (`expert::Phase::Approach`).
APPROACH = PHASES.index("approach")
#: How close to the recorded command a recomputed two-way detour must come to count as the
#: teacher's detour row (the recomputation matches to float rounding on recorded data).
REPRODUCED = 1e-3
#: The ball within this of the robot's centre (m): the detour's rows at the ball, where the
#: robot's feet reach it (the teacher's approach distance is 0.28 m) and a step forward pushes
#: the ball along instead of going around it.
AT_BALL_M = 0.3


@dataclass(frozen=True)
class OneWayDetour:
    """The teacher's geometry (`ExpertConfig::default`, `FieldGeometry::default`): metres."""

    approach_distance: float = 0.28
    detour_radius: float = 0.4
    goal_x: float = GOAL_X_M
    #: How far clockwise around the ball, radians, the one-way detour's target lies.
    step: float = math.pi / 3

    def command(self, pose: np.ndarray, ball: np.ndarray, target_side: float, one_way: bool) -> tuple[np.ndarray, bool]:
        """The approach command at one state and whether it is the detour's; `one_way` picks
        the relabelled detour, else the teacher's two-way one."""
        goal = np.array([target_side * self.goal_x, 0.0])
        to_goal = _unit(goal - ball)
        from_ball = pose[:2] - ball
        along = float(from_ball @ to_goal)
        detour = along > -self.approach_distance * 0.5 and float(np.linalg.norm(from_ball)) < self.detour_radius * 2.5
        if not detour:
            target = ball - to_goal * self.approach_distance
        elif one_way:
            angle = math.atan2(from_ball[1], from_ball[0]) - self.step
            target = ball + self.detour_radius * np.array([math.cos(angle), math.sin(angle)])
        else:
            side = _perp(to_goal) if to_goal[0] * from_ball[1] - to_goal[1] * from_ball[0] >= 0.0 else -_perp(to_goal)
            target = ball + _unit(side - to_goal * 0.6) * self.detour_radius
        ball_local = _to_robot(pose, ball)
        return walk_towards(_to_robot(pose, target), math.atan2(ball_local[1], ball_local[0])), detour

    def detour_rows(self, episode: Episode) -> tuple[np.ndarray, np.ndarray]:
        """Which of `episode`'s rows are the teacher's detour (mask) and their one-way labels."""
        if episode.robot_pose is None or episode.ball is None:
            raise ValueError(f"episode {episode.seed} holds no ground truth (robot pose, ball): re-record it")
        labels = episode.command.copy()
        mask = np.zeros(len(episode), bool)
        if len(episode) == 0:
            return mask, labels
        target_side = 1.0 if episode.ball[0, 0] >= 0.0 else -1.0
        for i in np.flatnonzero(episode.phase == APPROACH):
            pose = episode.robot_pose[i].astype(np.float64)
            ball = episode.ball[i].astype(np.float64)
            two_way, detour = self.command(pose, ball, target_side, one_way=False)
            if detour and np.abs(two_way - episode.command[i]).max() < REPRODUCED:
                mask[i] = True
                labels[i] = self.command(pose, ball, target_side, one_way=True)[0]
        return mask, labels

    def at_ball_rows(self, episodes: list[Episode]) -> np.ndarray:
        """Which rows of `episodes` (concatenated) are the teacher's detour with the ball within
        `AT_BALL_M`; an episode without ground truth has none."""
        masks = []
        for episode in episodes:
            if episode.robot_pose is None or episode.ball is None:
                masks.append(np.zeros(len(episode), bool))
                continue
            mask, _ = self.detour_rows(episode)
            offset = episode.ball.astype(np.float64) - episode.robot_pose[:, :2].astype(np.float64)
            masks.append(mask & (np.hypot(offset[:, 0], offset[:, 1]) < AT_BALL_M))
        return np.concatenate(masks) if masks else np.zeros(0, bool)

    def relabelled(self, episodes: list[Episode]) -> tuple[list[Episode], np.ndarray]:
        """`episodes` with the one-way labels on their detour rows, and which rows those are
        (all episodes' rows, concatenated)."""
        out, masks = [], []
        for episode in episodes:
            mask, labels = self.detour_rows(episode)
            out.append(dataclasses.replace(episode, command=labels))
            masks.append(mask)
        return out, (np.concatenate(masks) if masks else np.zeros(0, bool))


def walk_towards(target: np.ndarray, face: float, speed: float = 1.0) -> np.ndarray:
    """`expert.rs`'s `walk_towards`: an omnidirectional walk to `target` (robot frame) while
    turning to `face` (radians), forward slowed while the turn is large; clamped as
    `SpeedCommand::new` clamps."""
    distance = float(np.linalg.norm(target))
    direction = target / distance if distance > 0.0 else np.zeros(2)
    gain = min(distance * 2.5, 1.0) * speed
    turn = min(max(face * 1.5, -1.0), 1.0)
    slow_for_turn = 1.0 - 0.6 * min(abs(face) / math.pi, 1.0)
    command = np.array([direction[0] * gain * slow_for_turn, direction[1] * gain * 1.2, turn])
    return np.clip(command, -1.0, 1.0)


def _to_robot(pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    """A field point in the robot's frame: x forward, y left."""
    d = point - pose[:2]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def _perp(v: np.ndarray) -> np.ndarray:
    return np.array([-v[1], v[0]])


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0.0 else np.zeros(2)
