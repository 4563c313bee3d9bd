"""Two runs of the same seeds compared seed by seed: goals, agreement, the goals only one run
scored and the exact McNemar test on them; runs of other seeds are refused."""

import json

import pytest

from dribble_models import paired_runs


def test_discordant_goals_and_the_exact_test():
    first = {1: "goal", 2: "goal", 3: "goal", 4: "ball_out", 5: "time_limit"}
    second = {1: "goal", 2: "time_limit", 3: "goal", 4: "time_limit", 5: "goal"}
    row = paired_runs.compare(first, second)
    assert row["goals"] == [3, 3] and row["episodes"] == 5 and row["seeds"] == "1..5"
    assert row["same_outcome"] == 2  # seeds 1 and 3 (4: ball out against the time limit)
    assert (row["goal_only_first"], row["goal_only_second"]) == (1, 1)
    assert row["mcnemar_p"] == 1.0
    # Six goals only in one run, none only in the other: 2 / 64.
    assert paired_runs.mcnemar_p(6, 0) == pytest.approx(2 / 64)
    assert paired_runs.mcnemar_p(0, 0) == 1.0


def test_runs_of_other_seeds_are_refused():
    with pytest.raises(SystemExit, match="other seeds"):
        paired_runs.compare({1: "goal", 2: "goal"}, {1: "goal", 3: "goal"})


def test_rows_collect_by_label_and_the_table_is_rewritten(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"episodes": [{"seed": 7, "outcome": "goal"}, {"seed": 8, "outcome": "goal"}]}))
    b.write_text(json.dumps({"engine": None, "episodes": [{"seed": 7, "outcome": "goal"}, {"seed": 8, "outcome": "ball_out"}]}))
    out = tmp_path / "ab"
    for label in ("clean", "randomized", "clean"):
        assert paired_runs.main(["--run", "4", str(a), "--run", "1", str(b), "--label", label, "--out", str(out)]) == 0
    rows = json.loads(out.with_suffix(".json").read_text())
    assert list(rows) == ["clean", "randomized"]
    text = out.with_suffix(".md").read_text()
    assert "| clean: 4 against 1 | 7..8 | 2 / 2 (0.34-1.00) | 1 / 2 (0.09-0.91) | 1 of 2 | 1 | 0 | 1.00 |" in text


def test_seeds_cut_both_runs_and_must_all_be_there(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"episodes": [{"seed": s, "outcome": "goal"} for s in range(10, 14)]}))
    b.write_text(json.dumps({"episodes": [{"seed": s, "outcome": "goal"} for s in range(10, 12)]}))
    out = tmp_path / "ab"
    assert paired_runs.main(["--run", "4", str(a), "--run", "1", str(b), "--label", "x", "--out", str(out), "--seeds", "10..12"]) == 0
    assert json.loads(out.with_suffix(".json").read_text())["x"]["seeds"] == "10..11"
    with pytest.raises(SystemExit, match="no episode of the seeds"):
        paired_runs.main(["--run", "4", str(a), "--run", "1", str(b), "--label", "x", "--out", str(out), "--seeds", "10..13"])


def test_the_committed_table_is_what_the_committed_rows_give():
    from pathlib import Path

    performance = Path(__file__).resolve().parents[1] / "performance"
    rows = json.loads((performance / "camera-samples-selection.json").read_text())
    assert (performance / "camera-samples-selection.md").read_text() == paired_runs.table(rows)
