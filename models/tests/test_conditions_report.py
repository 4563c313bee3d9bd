"""The conditions table: goals, intervals, the ratio to clean and failure classes come from the
summaries, the clean reference is the same policy's on the same seeds and engine, and the
committed table is what the committed summaries give."""

import json
from pathlib import Path

import pytest

from dribble_models import conditions_report

ENGINE = "compiled (avx2+fma, winograd)"


def _summary(path: Path, seeds: range, goals: int, engine: str = ENGINE, failure: str = "walked_off") -> None:
    """`goals` of the episodes are goals, the misses spread evenly among them."""
    path.parent.mkdir(parents=True, exist_ok=True)
    missed = {round(k * len(seeds) / (len(seeds) - goals)) for k in range(len(seeds) - goals)} if goals < len(seeds) else set()
    episodes = [
        {"seed": s, "outcome": "time limit" if i in missed else "goal", "failure_class": failure if i in missed else None}
        for i, s in enumerate(seeds)
    ]
    path.write_text(json.dumps({"engine": engine, "episodes": episodes}))


def test_the_table_compares_each_condition_with_clean_on_the_same_seeds(tmp_path):
    root, policies = tmp_path / "conditions", tmp_path / "policy"
    _summary(policies / "best" / "fresh.json", range(30_000, 30_100), 90)
    runs = root / "best" / "fresh20"
    _summary(runs / "noise-3.json", range(30_000, 30_020), 9, failure="lost_the_ball")
    _summary(runs / "exposure-3.json", range(30_000, 30_020), 0)
    text = conditions_report.report(root, policies)
    # Clean is the first 20 fresh seeds of the policy's own run: 18 of them are goals.
    assert "| clean | - | 18 / 20 (0.70-0.97) | 1.00 | walked off 2 |" in text
    assert "| noise | 3 | 9 / 20 (0.26-0.66) | 0.50 | lost the ball 11 |" in text
    # Rows follow the simulator's order of conditions, not the files' names.
    assert text.index("| exposure |") < text.index("| noise |")


def test_runs_on_other_engines_or_seeds_than_clean_are_refused(tmp_path):
    root, policies = tmp_path / "conditions", tmp_path / "policy"
    _summary(policies / "best" / "fresh.json", range(30_000, 30_100), 90)
    runs = root / "best" / "fresh20"
    _summary(runs / "noise-3.json", range(30_000, 30_020), 9, engine="tract")
    with pytest.raises(conditions_report.ReportError, match="ran on tract"):
        conditions_report.report(root, policies)
    # Runs beside each other on other seeds than the first one (whose seeds cut the clean run).
    _summary(runs / "noise-3.json", range(30_000, 30_020), 9)
    _summary(runs / "exposure-3.json", range(30_001, 30_021), 9)
    with pytest.raises(conditions_report.ReportError, match="other seeds"):
        conditions_report.report(root, policies)


def test_runs_on_one_sample_frames_are_refused(tmp_path):
    root, policies = tmp_path / "conditions", tmp_path / "policy"
    _summary(policies / "best" / "fresh.json", range(30_000, 30_100), 90)
    path = root / "best" / "fresh20" / "noise-3.json"
    _summary(path, range(30_000, 30_020), 9)
    conditions_report.report(root, policies)
    summary = json.loads(path.read_text())
    path.write_text(json.dumps({**summary, "camera_samples": 1}))
    with pytest.raises(conditions_report.ReportError, match="1 camera sample"):
        conditions_report.report(root, policies)


def test_the_shipped_picture_takes_the_hundred_fresh_seeds_over_the_first_twenty(tmp_path):
    root, policies = tmp_path / "conditions", tmp_path / "policy"
    _summary(policies / "best" / "fresh.json", range(30_000, 30_100), 80)
    _summary(root / "best" / "fresh20" / "light-3.json", range(30_000, 30_020), 8)
    _summary(root / "best" / "fresh20" / "light-5.json", range(30_000, 30_020), 4)
    _summary(root / "best" / "fresh" / "light-3.json", range(30_000, 30_100), 72)
    points = {(p["condition"], p["severity"]): p for p in conditions_report.ratio_points(root, policies, "best")}
    assert set(points) == {("light", 3), ("light", 5)}
    # Severity 3 from the hundred: 72 of 100 against the clean 80 of 100.
    assert points[("light", 3)]["episodes"] == 100
    assert points[("light", 3)]["ratio"] == pytest.approx(0.9)
    # Severity 5 from the twenty, against the clean goals on those twenty.
    clean_twenty = sum(e["outcome"] == "goal" for e in json.loads((policies / "best" / "fresh.json").read_text())["episodes"][:20])
    assert points[("light", 5)]["ratio"] == pytest.approx(4 / clean_twenty)
    low, high = conditions_report.wilson(4, 20)
    assert points[("light", 5)]["low"] == pytest.approx(low * 20 / clean_twenty)
    assert points[("light", 5)]["high"] == pytest.approx(high * 20 / clean_twenty)
    for file in ("HOST_MODEL", "ROBOT_MODEL"):
        (policies / file).write_text("best\n")
    conditions_report.plot_shipped(root, policies, tmp_path / "shipped.png")
    assert (tmp_path / "shipped.png").read_bytes().startswith(b"\x89PNG")
    # A policy just shipped has played no condition yet: its panel says so, and the picture is drawn.
    (policies / "ROBOT_MODEL").write_text("just-shipped\n")
    assert conditions_report.ratio_points(root, policies, "just-shipped") == []
    conditions_report.plot_shipped(root, policies, tmp_path / "shipped-one-empty.png")
    assert (tmp_path / "shipped-one-empty.png").read_bytes() != (tmp_path / "shipped.png").read_bytes()


def test_the_committed_table_is_what_the_committed_summaries_give():
    assert conditions_report.main(["--check"]) == 0
