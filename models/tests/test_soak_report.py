"""The book's soak page: one row per published run, the verdict by the run's own limits."""

import json

from dribble_models import soak_report


def _run(**changes) -> dict:
    run = {
        "policy": "models/policy/m/policy.toml",
        "isa": "ssse3",
        "engine": "compiled (ssse3)",
        "minutes": 60.0,
        "commands": 360000,
        "computed": 108000,
        "lost": 0,
        "missed": 10,
        "missed_share": 10 / 360000,
        "latency_us": {"p50": 100.0, "p99": 600.0, "max": 2000.0},
        "rss_kib": {"after_warm_up": 49000, "end": 49000, "max": 49000, "growth": 0},
        "open_files": {"start": 56, "end": 56},
        "limits": {"max_rss_growth_kib": 256, "max_missed_share": 0.001},
        "faults": [{"fault": "camera_pause", "passed": True, "detail": ""}],
    }
    run.update(changes)
    return run


def test_a_clean_hour_passes_and_each_broken_criterion_is_named():
    assert soak_report.verdict(_run()) == "passed"
    assert soak_report.verdict(_run(lost=2)) == "failed: 2 lost"
    assert soak_report.verdict(_run(missed_share=0.002)) == "failed: misses over 0.1 %"
    grown = _run(rss_kib={"after_warm_up": 1, "end": 400, "max": 400, "growth": 399})
    assert soak_report.verdict(grown) == "failed: memory grew 399 KiB"
    refused = _run(faults=[{"fault": "second_controller", "passed": False, "detail": ""}])
    assert soak_report.verdict(refused) == "failed: fault second_controller"


def test_the_soaks_own_account_is_the_verdict_where_soak_json_holds_it():
    # Written by `dribble soak` since it records its failures: they are the verdict, even
    # where the figures alone would say otherwise (a criterion the page does not re-state).
    assert soak_report.verdict(_run(failures=[])) == "passed"
    both = ["2 commands lost", "open files grew from 56 to 57"]
    assert soak_report.verdict(_run(failures=both)) == "failed: 2 commands lost; open files grew from 56 to 57"
    assert soak_report.verdict(_run(lost=0, failures=["no command arrived"])) == "failed: no command arrived"


def test_the_page_has_a_row_and_a_plot_per_published_run(tmp_path):
    (tmp_path / "ssse3.json").write_text(json.dumps(_run()))
    (tmp_path / "ssse3.png").write_bytes(b"png")
    (tmp_path / "widest.json").write_text(json.dumps(_run(engine=None, isa=None, faults=[])))
    page = soak_report.page(tmp_path)
    rows = [line for line in page.splitlines() if line.startswith("| ssse3") or line.startswith("| widest")]
    assert len(rows) == 2
    assert "compiled (ssse3)" in rows[0] and "1 of 1 answered" in rows[0] and rows[0].endswith("| passed |")
    assert "the widest this CPU runs" in rows[1]
    assert "cross/soak/ssse3.png" in page and "cross/soak/widest.png" not in page
