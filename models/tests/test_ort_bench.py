"""The onnxruntime reference benchmark runs on every fixture kind and reports ordered figures."""

import json

from dribble_models import ort_bench


def test_reports_each_kind_with_ordered_quantiles(tmp_path, capsys):
    out = tmp_path / "ort.json"
    assert ort_bench.main(["--runs", "20", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["threads"] == 1
    assert set(report["kinds"]) == {"CNN", "CNN int8", "H-CNN", "R-CNN"}
    for figures in report["kinds"].values():
        assert 0 < figures["p10_us"] <= figures["median_us"] <= figures["p90_us"]
    printed = capsys.readouterr().out
    assert "CNN" in printed and "median" in printed


def test_refuses_too_few_runs():
    try:
        ort_bench.main(["--runs", "3"])
    except SystemExit as exit:
        assert exit.code == 2
    else:
        raise AssertionError("--runs 3 was accepted")


def test_times_a_shipped_policy_by_its_directory_name(tmp_path, capsys):
    from pathlib import Path

    fixture = Path(ort_bench.FIXTURES) / "cnn-int8"
    out = tmp_path / "ort.json"
    assert ort_bench.main(["--runs", "10", "--json", str(out), "--policy", str(fixture)]) == 0
    assert set(json.loads(out.read_text())["kinds"]) == {"cnn-int8"}
    try:
        ort_bench.main(["--runs", "10", "--policy", str(tmp_path)])
    except SystemExit as exit:
        assert exit.code == 2
    else:
        raise AssertionError("a directory without policy.toml was accepted")
