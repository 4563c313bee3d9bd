"""The episode-rate table: a setting's runs must agree episode by episode, the rates divide by
wall time and busy cores, and the comparison counts episodes that end the same way."""

import pytest

from dribble_models import episode_rate


def _run(wall: float, cores: float, outcomes: dict[str, str]) -> dict:
    return {"wall_s": wall, "machine_cores_busy": cores, "outcomes": outcomes, "durations_s": {s: 30.0 for s in outcomes}}


def test_rates_are_per_hour_and_per_busy_core_hour():
    outcomes = {"1": "goal", "2": "time_limit"}
    summary = episode_rate.summarise(4, [_run(100.0, 2.0, outcomes), _run(80.0, 1.5, outcomes), _run(90.0, 1.8, outcomes)], 2)
    assert summary["wall_s"] == 90.0 and summary["machine_cores_busy"] == 1.8
    assert summary["episodes_per_hour"] == 80
    assert summary["episodes_per_core_hour"] == 44
    assert summary["goals"] == 1 and summary["simulated_s"] == 60.0


def test_runs_of_one_setting_that_end_differently_are_refused():
    with pytest.raises(SystemExit, match="outcomes differ"):
        episode_rate.summarise(1, [_run(50.0, 1.0, {"1": "goal"}), _run(50.0, 1.0, {"1": "ball_out"})], 1)


def test_the_table_says_how_much_faster_and_how_many_episodes_agree():
    four = episode_rate.summarise(4, [_run(200.0, 1.6, {"1": "goal", "2": "goal"})], 2)
    one = episode_rate.summarise(1, [_run(100.0, 1.6, {"1": "goal", "2": "ball_out"})], 2)
    text = episode_rate.table({"settings": [four, one], "same_outcomes": 1})
    assert "| 4 | 2 | 2 | - | 60 | 200 | 200 | 36 | 1.60 | 22 | 1.00x |" in text
    assert "| 1 | 2 | 1 | 1 of 2 | 60 | 100 | 100 | 72 | 1.60 | 45 | 2.00x |" in text


def test_the_committed_table_is_what_the_committed_run_gives():
    from pathlib import Path
    import json

    performance = Path(__file__).resolve().parents[1] / "performance"
    result = json.loads((performance / "episode-rate.json").read_text())
    assert (performance / "episode-rate.md").read_text() == episode_rate.table(result)
