"""LeRobot's convention for `--env.type=dribble`: importing `gym_dribble` registers the gym id
`gym_dribble/NaoDribble-v0` (dribble_models.lerobot_eval says what it is)."""

from dribble_models.lerobot_eval import register

register()
