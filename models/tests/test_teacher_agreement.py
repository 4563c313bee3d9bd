"""The rows a teacher's rule changes are counted on the same states only."""

import copy

import numpy as np

from dribble_models import lerobot_format, teacher_agreement
from test_lerobot_format import episode


def test_changed_rows_are_counted_where_the_states_agree(tmp_path):
    first = episode(60, 6)
    second = copy.deepcopy(first)
    second.command[1, 2] += 0.5  # the second teacher turns otherwise in row 1
    second.top[4, 0, 0] ^= 1  # from row 4 on the robot saw something else: not compared
    second.command[5, 0] += 0.5
    lerobot_format.write_dribble([(first, {})], tmp_path / "a", teacher="observable")
    lerobot_format.write_dribble([(second, {})], tmp_path / "b", teacher="detector")
    result = teacher_agreement.compare(tmp_path / "a", tmp_path / "b")
    assert result["teachers"] == ("observable", "detector") and result["recorded"] == 6
    assert sum(result["compared"].values()) == 4
    assert sum(result["changed"].values()) == 1
    phase = teacher_agreement.PHASES[int(first.phase[1])]
    assert result["changed"][phase] == 1
    assert "| all | 4 | 1 | 25.0% |" in teacher_agreement.table(result)
    assert np.array_equal(first.top[0], second.top[0])
