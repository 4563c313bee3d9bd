"""The one rule that chooses the shipped model and a DAgger iteration (shipping_rules.py), as
results.py and dagger_report.py both apply it."""

import json
from pathlib import Path

import pytest

from dribble_models import dagger_report, results
from dribble_models.shipping_rules import Candidate, SelectionError, choose, engine_of, read_selection


def write_run(path: Path, seeds, goals: set[int]) -> Path:
    episodes = [{"seed": s, "outcome": "goal" if s in goals else "time_limit"} for s in seeds]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"engine": "compiled (avx2+fma)", "episodes": episodes}))
    return path


def model(tmp_path: Path, name: str, selected: set[int] | None, tested: set[int], validation: float) -> dict:
    directory = tmp_path / name
    if selected is not None:
        write_run(directory / "select.json", range(90, 100), selected)
    write_run(directory / "eval.json", range(10000, 10020), tested)
    return {"directory": str(directory), "training": {"validation_error": validation}}


def test_selection_goals_decide_even_where_the_test_episodes_say_otherwise(tmp_path):
    # "few" scores more on the test episodes; "many" on the selection episodes. The test
    # episodes are for reporting only: "many" is chosen, whatever its validation error.
    rows = [
        model(tmp_path, "few", {90, 91}, set(range(10000, 10018)), 0.10),
        model(tmp_path, "many", {90, 91, 92, 93}, {10000}, 0.30),
    ]
    assert Path(results.choose(rows)["directory"]).name == "many"
    assert "4 goals in 10 selection episodes" in rows[1]["selection"]
    iterations = [
        {"iteration": 1, "directory": rows[0]["directory"], "validation_error": 0.10},
        {"iteration": 2, "directory": rows[1]["directory"], "validation_error": 0.30},
    ]
    assert dagger_report.choose(iterations)["iteration"] == 2


def test_a_tie_goes_to_the_lower_validation_error_and_a_missing_run_ranks_last(tmp_path):
    rows = [
        model(tmp_path, "never-evaluated", None, set(range(10000, 10020)), 0.01),
        model(tmp_path, "worse", {90, 91}, set(), 0.20),
        model(tmp_path, "better", {95, 96}, set(), 0.15),
    ]
    assert Path(results.choose(rows)["directory"]).name == "better"
    assert "no selection run" in rows[0]["selection"]
    iterations = [{"iteration": i, "directory": r["directory"], "validation_error": r["training"]["validation_error"]} for i, r in enumerate(rows)]
    assert dagger_report.choose(iterations)["iteration"] == 2


def test_test_seeds_in_a_selection_file_are_refused(tmp_path):
    for seeds in ([90, 10005], [20000, 30042]):
        path = write_run(tmp_path / f"{seeds[1]}.json", seeds, set())
        with pytest.raises(SelectionError, match="reporting only"):
            read_selection(path)


def test_the_choice_is_made_on_the_largest_seed_set_and_other_runs_rank_last(tmp_path):
    # "old" scored every one of the retired seeds 90..99; "new" 1 of the 50 selection seeds.
    # They cannot be compared: the choice is made on the larger set, "old" must run again.
    old = read_selection(write_run(tmp_path / "old.json", range(90, 100), set(range(90, 100))))
    new = read_selection(write_run(tmp_path / "new.json", range(20000, 20050), {20000}))
    candidates = [Candidate("old", old, 0.1), Candidate("new", new, 0.2)]
    assert choose(candidates).name == "new"
    assert "not the chosen set 20000..20049 (50)" in candidates[0].reason(new.seeds)
    with pytest.raises(SelectionError):
        choose([])


def test_runs_by_different_engines_on_the_same_seeds_are_refused(tmp_path):
    a = read_selection(write_run(tmp_path / "a.json", range(20000, 20050), {20000}))
    path = write_run(tmp_path / "b.json", range(20000, 20050), {20001})
    path.write_text(path.read_text().replace("compiled (avx2+fma)", "tract"))
    b = read_selection(path)
    with pytest.raises(SelectionError, match="different engines"):
        choose([Candidate("a", a, 0.1), Candidate("b", b, 0.1)])


def test_kernels_a_network_lowers_to_do_not_make_candidates_incomparable(tmp_path):
    # A wide float network runs Winograd's filtering, a narrow one the direct sum, an int8 one
    # integer kernels: each as it ships, on the one engine and instruction set the evaluation
    # chose; compared. Another instruction set or another engine is still refused.
    def run(name, label, goals):
        path = write_run(tmp_path / f"{name}.json", range(20000, 20050), set(range(20000, 20000 + goals)))
        path.write_text(path.read_text().replace("compiled (avx2+fma)", label))
        return read_selection(path)

    wide = Candidate("wide", run("wide", "compiled (avx2+fma, winograd)", 40), 0.1)
    narrow = Candidate("narrow", run("narrow", "compiled (avx2+fma)", 42), 0.2)
    assert choose([wide, narrow]).name == "narrow"
    assert engine_of("compiled (avx2+fma, int8)") == engine_of("compiled (avx2+fma)") == "compiled (avx2+fma)"
    assert engine_of("compiled (avx512, winograd)") == "compiled (avx512)"
    assert engine_of("tract") == "tract" and engine_of(None) is None
    other_isa = Candidate("other", run("other", "compiled (avx512, winograd)", 45), 0.1)
    with pytest.raises(SelectionError, match="different engines"):
        choose([wide, narrow, other_isa])


def test_under_randomized_conditions_clean_and_randomized_goals_count_together(tmp_path):
    seeds = range(20000, 20010)

    def row(name, clean, randomized, validation):
        directory = tmp_path / name
        write_run(directory / "select.json", seeds, set(seeds[:clean]))
        if randomized is not None:
            write_run(directory / "select_randomized.json", seeds, set(seeds[:randomized]))
        return {"directory": str(directory), "training": {"validation_error": validation}}

    # Clean only, "clean-best" wins; once any candidate was played under randomized conditions
    # the goals of both runs count: "robust" (7 + 7) over "clean-best" (9 + 2), and "unplayed",
    # however many clean goals it has, ranks last until it is played so.
    rows = [row("clean-best", 9, None, 0.1), row("robust", 7, None, 0.2)]
    assert Path(results.choose(rows)["directory"]).name == "clean-best"
    rows = [row("clean-best", 9, 2, 0.1), row("robust", 7, 7, 0.2), row("unplayed", 10, None, 0.05)]
    assert Path(results.choose(rows)["directory"]).name == "robust"
    assert "7 goals in 10 selection episodes clean and 7 under randomized conditions (14 of 20)" in rows[1]["selection"]
    assert "ranked last until played so" in rows[2]["selection"]
    # A randomized run on other seeds than the clean one does not count.
    write_run(tmp_path / "robust" / "select_randomized.json", range(20010, 20020), set(range(20010, 20020)))
    assert Path(results.choose(rows)["directory"]).name == "clean-best"
    # Nor does one by another engine: refused, as for clean runs.
    path = write_run(tmp_path / "robust" / "select_randomized.json", seeds, set(seeds))
    path.write_text(path.read_text().replace("compiled (avx2+fma)", "tract"))
    with pytest.raises(SelectionError, match="different engines"):
        results.choose(rows)


def test_the_committed_choice_follows_the_rule():
    """models/policy/HOST_MODEL is what the rule picks from the committed rows: the results
    table's (results.ROWS, as scripts/results reads them), not every committed candidate (one
    with no test and fresh runs yet is no row and cannot be shipped)."""
    policy = Path(__file__).resolve().parents[1] / "policy"
    shipped = (policy / "HOST_MODEL").read_text().strip()
    rows = []
    for directory in results.rows_in(policy):
        manifest = results.load(directory / "policy.toml")
        rows.append({"directory": str(directory), "training": manifest["training"]})
    assert Path(results.choose(rows)["directory"]).name == shipped
