import json

from dribble_models import eval_summary


def episode(seed, outcome, robot, ball):
    return {"seed": seed, "outcome": outcome, "duration_s": 12.5, "computed_commands": 375, "failure": None, "robot": robot, "ball": ball}


def test_a_summary_keeps_outcomes_and_measures_the_paths(tmp_path):
    # The ball starts at x = 2 (target goal at +4.5), the robot walks 3 m and pushes it 1 m on.
    robot = [[-1.0, 0.0], [0.0, 0.0], [2.0, 0.0]]
    ball = [[2.0, 0.0], [2.0, 0.0], [3.0, 0.0]]
    trajectories = {"engine": "compiled (avx2+fma)", "episodes": [episode(7, "time_limit", robot, ball)]}
    source, target = tmp_path / "paths.json", tmp_path / "summary.json"
    source.write_text(json.dumps(trajectories))
    assert eval_summary.main([str(source), str(target)]) == 0
    written = json.loads(target.read_text())
    assert written["engine"] == "compiled (avx2+fma)"
    (summary,) = written["episodes"]
    assert summary["seed"] == 7 and summary["outcome"] == "time_limit"
    assert summary["walked_m"] == 3.0
    assert summary["closest_to_ball_m"] == 1.0
    assert summary["ball_toward_goal_m"] == 1.0
    assert summary["ball_to_goal_end_m"] == 1.5
    assert summary["standing_share"] == 0.0  # three samples: less than a second
    assert "robot" not in summary


def test_standing_is_the_share_of_seconds_with_less_than_5_cm_moved(tmp_path):
    # 10 Hz: two seconds standing at the start, then walking 1 m/s for two seconds.
    robot = [[0.0, 0.0]] * 20 + [[0.1 * i, 0.0] for i in range(1, 21)]
    ball = [[2.0, 0.0]] * 40
    summary = eval_summary.summarise_episode(episode(1, "time_limit", robot, ball))
    # 30 one-second windows: those ending at samples 10..19 stood (10), the rest walked.
    assert summary["standing_share"] == round(10 / 30, 3)


def test_a_file_that_is_not_an_evaluation_is_refused(tmp_path, capsys):
    source = tmp_path / "paths.json"
    source.write_text('{"something": []}')
    assert eval_summary.main([str(source), str(tmp_path / "out.json")]) == 2
    assert "not a `dribble eval --trajectories` file" in capsys.readouterr().err


def test_files_from_before_the_engine_was_recorded_summarise_without_one(tmp_path):
    source, target = tmp_path / "paths.json", tmp_path / "summary.json"
    source.write_text(json.dumps({"episodes": [episode(3, "goal", [[0.0, 0.0]], [[4.5, 0.0]])]}))
    assert eval_summary.main([str(source), str(target)]) == 0
    assert json.loads(target.read_text())["engine"] is None


def test_camera_samples_are_kept_only_when_not_the_default_four(tmp_path):
    source, target = tmp_path / "paths.json", tmp_path / "summary.json"
    episodes = [episode(3, "goal", [[0.0, 0.0]], [[4.5, 0.0]])]
    for written, kept in [(None, None), (4, None), (1, 1)]:
        file = {"engine": "tract", "episodes": episodes}
        if written is not None:
            file["camera_samples"] = written
        source.write_text(json.dumps(file))
        assert eval_summary.main([str(source), str(target)]) == 0
        assert json.loads(target.read_text()).get("camera_samples") == kept


def test_each_failure_has_one_class_from_its_paths():
    far_ball = [[3.0, 0.0]] * 30
    still = [[0.0, 0.0]] * 30
    spinning = dict(episode(1, "time_limit", still, far_ball), heading=[0.3 * i for i in range(30)])
    assert eval_summary.summarise_episode(spinning)["failure_class"] == "turned_in_place"
    assert eval_summary.summarise_episode(spinning)["turned_rad"] == round(0.3 * 29, 3)
    # Headings that wrap at ±pi are one small turn, not a full circle.
    wobbling = dict(episode(2, "time_limit", still, far_ball), heading=[3.1, -3.1] * 15)
    assert eval_summary.summarise_episode(wobbling)["failure_class"] == "stood"
    walking = [[0.1 * i, 1.0] for i in range(30)]  # 2.9 m, never within 0.3 m of (3, 0)
    assert eval_summary.summarise_episode(dict(episode(3, "time_limit", walking, far_ball), heading=[0.0] * 30))["failure_class"] == "walked_off"
    reached = [[0.1 * i, 0.0] for i in range(30)]  # ends 0.1 m from the ball
    assert eval_summary.summarise_episode(episode(4, "time_limit", reached, far_ball))["failure_class"] == "lost_the_ball"
    # Reaching the ball in 0.6 s and standing there the rest of the episode.
    reached_then_still = [[min(0.5 * i, 2.8), 0.0] for i in range(30)]
    stood = eval_summary.summarise_episode(episode(9, "time_limit", reached_then_still, far_ball))
    assert stood["standing_share"] >= 0.5 and stood["failure_class"] == "stood_at_the_ball"
    # A summary written before that class existed is read by today's rule; one without the
    # paths' figures keeps its class, and a goal has none.
    older = {**stood, "failure_class": "lost_the_ball"}
    assert eval_summary.class_of(older) == "stood_at_the_ball"
    assert eval_summary.class_of({"outcome": "time_limit", "failure_class": "stood"}) == "stood"
    assert eval_summary.class_of({"outcome": "ball_out"}) == "ball_out"
    assert eval_summary.class_of({**stood, "outcome": "goal"}) is None
    assert eval_summary.summarise_episode(episode(5, "ball_out", still, far_ball))["failure_class"] == "ball_out"
    assert eval_summary.summarise_episode(episode(6, "goal", reached, far_ball))["failure_class"] is None
    # Files without headings cannot tell standing from turning.
    assert eval_summary.summarise_episode(episode(7, "time_limit", still, far_ball))["failure_class"] == "stood_or_turned"
    seen = dict(episode(8, "goal", reached, far_ball), first_sighting_s=2.4)
    assert eval_summary.summarise_episode(seen)["first_sighting_s"] == 2.4


def test_seeds_keep_the_first_episodes_of_a_longer_run_and_refuse_missing_ones(tmp_path, capsys):
    path = [[0.0, 0.0], [0.0, 0.0]]
    trajectories = {"engine": "tract", "episodes": [episode(s, "goal", path, path) for s in (20000, 20001, 20002)]}
    source, target = tmp_path / "paths.json", tmp_path / "summary.json"
    source.write_text(json.dumps(trajectories))
    assert eval_summary.main([str(source), str(target), "--seeds", "20000..20002"]) == 0
    assert [e["seed"] for e in json.loads(target.read_text())["episodes"]] == [20000, 20001]
    assert eval_summary.main([str(source), str(target), "--seeds", "20001..20004"]) == 2
    assert "20003" in capsys.readouterr().err


def test_a_models_other_selection_runs_are_named_by_their_file():
    from dribble_models.results import selection_run_name

    assert selection_run_name("select_randomized") == "randomized"
    assert selection_run_name("select20_clean") == "clean-20"


def test_episodes_whose_controller_was_lost_are_refused_not_counted(tmp_path, capsys):
    robot, ball = [[0.0, 0.0]], [[2.0, 0.0]]
    episodes = [episode(5, "goal", robot, ball), episode(6, "controller_lost", robot, ball)]
    source, target = tmp_path / "paths.json", tmp_path / "summary.json"
    source.write_text(json.dumps({"episodes": episodes}))
    assert eval_summary.main([str(source), str(target)]) == 3
    assert "seeds 6 lost their controller" in capsys.readouterr().err
    assert not target.exists()
    # A paired look at seeds without the lost one summarises.
    assert eval_summary.main([str(source), str(target), "--seeds", "5..6"]) == 0


def test_a_runs_pieces_join_into_one_summary_only_where_they_are_one_run(tmp_path, capsys):
    from dribble_models import summary_join

    def piece(name, seeds, **identity):
        path = tmp_path / name
        episodes = [{"seed": s, "outcome": "goal" if s % 2 else "time_limit"} for s in seeds]
        path.write_text(json.dumps({"engine": "tract", "conditions": "noise:3", **identity, "episodes": episodes}))
        return str(path)

    target = tmp_path / "summary.json"
    pieces = [piece("b.json", [20, 21]), piece("a.json", [0, 1]), piece("c.json", [40, 41])]
    assert summary_join.main([str(target), *pieces]) == 0
    written = json.loads(target.read_text())
    assert [e["seed"] for e in written["episodes"]] == [0, 1, 20, 21, 40, 41]
    assert written["engine"] == "tract" and written["conditions"] == "noise:3"
    assert "goals: 3/6" in capsys.readouterr().out
    # A piece of another engine or condition, or one that repeats a seed: refused, nothing written.
    for other in [piece("d.json", [60], engine="compiled (avx2+fma)"), piece("e.json", [60], conditions="noise:5"), piece("f.json", [21])]:
        target.unlink(missing_ok=True)
        assert summary_join.main([str(target), *pieces, other]) == 2
        assert "are not one run" in capsys.readouterr().err
        assert not target.exists()
