"""The trainer: data checks, the R-CNN's windows against stepping, a tiny run of each kind
that the robot's own code (`dribble score`) loads and scores to the trainer's numbers.
No test here asserts how well anything learns."""

import hashlib
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from dribble_models import dataset as ds
from dribble_models.camera_effects import CameraMotion, light_patches
from dribble_models.networks import RCNN, ModalCNN, RCNNStep
from dribble_models.networks import CNN, PAPER_FILTERS, Filters
from dribble_models.one_way_detour import OneWayDetour
from dribble_models.shipped_weights import load_pruned_weights, load_shipped_weights
from dribble_models.augmentation import CameraAugment, mirrorable, mirrored
from dribble_models.command_metric import row_errors, sent_commands
from dribble_models.prediction import gating_features, predict_rcnn, to_input
from dribble_models.rcnn_windows import rcnn_forward_windows
from dribble_models.train import Rows, Training, main, parse_args, winner_takes_all_loss
from dribble_models.training_record import notes_of, start_sha256
from dribble_models.gating import gating_feature
from dribble_models.results import main as results_main

from test_dataset import dribble_binary


def write_dataset(directory: Path, seeds: list[int], rows: int, rng: np.random.Generator, twinned: tuple[int, ...] = (), driven: bool = False) -> Path:
    """A dataset in `dribble record`'s format with random thumbnails and commands; the
    episodes of the `twinned` seeds carry clean-twin thumbnails (`--clean-twin`); `driven`:
    policy-driven episodes (`policy_command`, commands past the range, and `expert_executed`)."""
    directory.mkdir(parents=True, exist_ok=True)
    entries = []
    for seed in seeds:
        file = f"episode_{seed:05}.npz"
        twin = {}
        if seed in twinned:
            twin = {
                "top_clean": rng.integers(0, 256, (rows, 120, 160), dtype=np.uint8),
                "bottom_clean": rng.integers(0, 256, (rows, 60, 80), dtype=np.uint8),
            }
        if driven:
            twin |= {
                "policy_command": rng.uniform(-1.5, 1.5, (rows, 3)).astype(np.float32),
                "expert_executed": rng.integers(0, 2, rows, dtype=np.uint8),
            }
        np.savez_compressed(
            directory / file,
            **twin,
            top=rng.integers(0, 256, (rows, 120, 160), dtype=np.uint8),
            bottom=rng.integers(0, 256, (rows, 60, 80), dtype=np.uint8),
            command=rng.uniform(-1, 1, (rows, 3)).astype(np.float32),
            robot_pose=np.zeros((rows, 3), np.float32),
            ball=np.zeros((rows, 2), np.float32),
            time_s=np.arange(rows) / 30.0,
            phase=rng.integers(0, 4, rows, dtype=np.uint8),
        )
        digest = hashlib.sha256((directory / file).read_bytes()).hexdigest()
        entries.append({"seed": seed, "file": file, "outcome": "time_limit", "rows": rows, "duration_s": rows / 30, "bytes": 0, "sha256": digest})
    index = {"format": 1, "project_version": "test", "simulator": {}, "expert": "", "episodes": entries, "content_hash": ds.content_hash(entries)}
    (directory / "dataset.json").write_text(json.dumps(index))
    return directory


def conditioned_data_and_model(tmp_path: Path, rng: np.random.Generator, seeds: list[int], conditions: list[str], twinned: tuple[int, ...] = ()):
    """A dataset of 6-row episodes recorded under `conditions` (one per seed), the trainer's
    common arguments for it, and a paper-width model trained on it to distil from."""
    train = write_dataset(tmp_path / "train", seeds, 6, rng, twinned=twinned)
    index = json.loads((train / "dataset.json").read_text())
    for entry, condition in zip(index["episodes"], conditions):
        entry["conditions"] = condition
    (train / "dataset.json").write_text(json.dumps(index))
    common = ["--kind", "cnn", "--dataset", str(train), "--epochs", "1", "--validation-episodes", "1", "--threads", "1"]
    big = tmp_path / "big"
    assert main([*common, "--out", str(big), "--checkpoint-dir", str(tmp_path / "c-big")]) == 0
    return train, common, big


def test_a_missing_or_changed_episode_is_named(tmp_path, rng):
    directory = write_dataset(tmp_path / "data", [1, 2], 5, rng)
    assert ds.load(directory).rows == 10
    (directory / "episode_00002.npz").unlink()
    with pytest.raises(ds.DatasetError, match="episode 2 is listed in dataset.json but episode_00002.npz is missing"):
        ds.load(directory)
    directory = write_dataset(tmp_path / "changed", [1], 5, rng)
    with open(directory / "episode_00001.npz", "ab") as file:
        file.write(b"x")
    with pytest.raises(ds.DatasetError, match="is not the file dataset.json lists"):
        ds.load(directory)
    with pytest.raises(ds.DatasetError, match=r"the episodes \[3\] were asked for"):
        ds.load(write_dataset(tmp_path / "short", [1, 2], 5, rng), require_seeds=[1, 3])


def test_the_vectorised_gating_feature_is_the_robots(rng):
    tops = rng.integers(0, 256, (6, 120, 160), dtype=np.uint8)
    bottoms = rng.integers(0, 256, (6, 60, 80), dtype=np.uint8)
    tops[0] = 255
    bottoms[1] = 51
    many = gating_features(tops, bottoms)
    for i in range(6):
        assert np.array_equal(many[i], gating_feature(tops[i], bottoms[i]))


def test_the_error_is_measured_on_what_the_controller_sends():
    expert = np.array([[0.5, 0.0, 1.0], [0.0, 0.0, 0.0]], np.float32)
    raw = np.array([[0.5, 0.0, 3.0], [np.nan, 1.0, 0.0]], np.float32)
    # 3.0 is clamped to 1.0; a NaN anywhere makes the whole command a stop.
    assert np.allclose(row_errors(raw, expert), [0.0, 0.0])


def test_rcnn_window_training_and_stepped_evaluation_agree(rng):
    model = RCNN().eval()
    steps = 230
    tops = rng.integers(0, 256, (steps, 120, 160), dtype=np.uint8)
    bottoms = rng.integers(0, 256, (steps, 60, 80), dtype=np.uint8)
    episode = ds.Episode(0, tops, bottoms, np.zeros((steps, 3), np.float32), np.zeros(steps, np.uint8))
    with torch.no_grad():
        windows = rcnn_forward_windows(model, to_input(tops), to_input(bottoms), window=100).numpy()
        step = RCNNStep(model)
        h, c = model.zero_state()
        stepped = []
        for i in range(steps):
            command, h, c = step(to_input(tops[i : i + 1]), to_input(bottoms[i : i + 1]), h, c)
            stepped.append(command.numpy()[0])
    whole = predict_rcnn(model, episode)
    assert np.abs(windows - np.array(stepped)).max() < 1e-5
    assert np.abs(whole - np.array(stepped)).max() < 1e-5


def run_score(policy: Path, data: Path, tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(dribble_binary()), "score", "--policy", str(policy), "--dataset", str(data), *extra],
        capture_output=True,
        text=True,
    )


@pytest.mark.parametrize("kind", ["cnn", "hcnn", "rcnn", "cnn --modes 2", "cnn --filters 8,16,4,8", "cnn --previous-command"])
def test_a_tiny_training_is_loaded_and_scored_by_the_robots_code(kind, tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2, 3], 24, rng)
    test = write_dataset(tmp_path / "test", [10000], 24, rng)
    out = tmp_path / kind.split()[0]
    argv = ["--kind", *kind.split(), "--dataset", str(train), "--test-dataset", str(test), "--out", str(out)]
    argv += ["--epochs", "1", "--validation-episodes", "1", "--batch-size", "16", "--window", "10", "--lanes", "2"]
    argv += ["--checkpoint-dir", str(tmp_path / "checkpoints"), "--threads", "1"]
    assert main(argv) == 0
    for name in ("policy.toml", "loss_curve.png", "scores.json"):
        assert (out / name).is_file(), name
    trainer = json.loads((out / "scores.json").read_text())
    for data, role in ((train, "train"), (test, "test")):
        result = run_score(out / "policy.toml", data, tmp_path, "--expect", role, "--json", str(tmp_path / f"{role}.json"))
        assert result.returncode == 0, result.stdout + result.stderr
        robot = json.loads((tmp_path / f"{role}.json").read_text())
        assert robot["rows"] == trainer[role]["rows"]
        assert abs(robot["error"] - trainer[role]["error"]) < 1e-4, (robot["error"], trainer[role]["error"])
        for phase, value in trainer[role]["phases"].items():
            if value["error"] is not None:
                assert abs(robot["phases"][phase]["error"] - value["error"]) < 1e-4, phase
    # The results table reads the same files scripts/train leaves (no closed loop here).
    for role in ("train", "test"):
        (out / f"score_{role}.json").write_text((tmp_path / f"{role}.json").read_text())
    table = tmp_path / "results.md"
    assert results_main(["--row", f"tiny={out}", "--out", str(table), "--choose", str(tmp_path / "HOST_MODEL")]) == 0
    row = next(line for line in table.read_text().splitlines() if line.startswith("| tiny |"))
    assert f"{trainer['test']['error']:.3f}" in row
    assert "| not recorded |" in row  # no closed loop here, so no engine for it
    (out / "eval.json").write_text(json.dumps({"engine": "compiled (sse4.2)", "episodes": [{"outcome": "goal", "duration_s": 20.0}]}))
    assert results_main(["--row", f"tiny={out}", "--out", str(table)]) == 0
    row = next(line for line in table.read_text().splitlines() if line.startswith("| tiny |"))
    # One goal in one episode: the Wilson 95 % interval 0.21-1.00; no fresh-seed run.
    assert "| 1 / 1 (0.21-1.00) | - | 20.0 s |" in row and "| compiled (sse4.2) |" in row
    (out / "eval.json").unlink()
    assert (tmp_path / "HOST_MODEL").read_text().strip() == out.name
    # Run again: the checkpoint is complete, so it resumes at the end and exports the same.
    manifest = (out / "policy.toml").read_text()
    assert main(argv) == 0
    assert (out / "policy.toml").read_text() == manifest


def test_a_narrow_cnn_says_so_and_is_never_mixed_with_the_papers_widths(tmp_path, rng, capsys):
    train = write_dataset(tmp_path / "train", [1, 2], 12, rng)
    common = ["--kind", "cnn", "--dataset", str(train), "--epochs", "1", "--validation-episodes", "1", "--threads", "1"]
    narrow = tmp_path / "narrow"
    assert main([*common, "--filters", "8,16,4,8", "--out", str(narrow), "--checkpoint-dir", str(tmp_path / "c1")]) == 0
    assert "filters 8,16,4,8 (top 8 then 16, bottom 4 then 8; the paper's 16,32,8,16)" in (narrow / "policy.toml").read_text()
    # A start of other widths is refused, from a checkpoint or from the shipped weights.
    for start, reason in ((tmp_path / "c1" / "cnn.pt", "has the filters 8,16,4,8; this run trains 16,32,8,16"),
                          (narrow, "features.top.0.weight is float32 [8, 1, 5, 5], the network's is float32 [16, 1, 5, 5]")):
        capsys.readouterr()
        assert main([*common, "--out", str(tmp_path / "paper"), "--init-from", str(start), "--checkpoint-dir", str(tmp_path / "c2")]) == 2
        assert reason in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--kind", "rcnn", "--dataset", str(train), "--out", str(tmp_path / "r"), "--filters", "8,16,4,8"])


@pytest.mark.parametrize("seed,name", [(20_000, "selection"), (10_005, "test"), (30_099, "fresh")])
def test_the_seeds_kept_for_choosing_and_reporting_are_never_trained_on(tmp_path, rng, capsys, seed, name):
    clean = write_dataset(tmp_path / "train", [1, 2, 3], 6, rng)
    reserved = write_dataset(tmp_path / "reserved", [4, seed], 6, rng)
    base = ["--kind", "cnn", "--epochs", "1", "--validation-episodes", "1", "--threads", "1"]
    base += ["--checkpoint-dir", str(tmp_path / "checkpoints")]
    # As the training dataset, and as an added one (a DAgger round).
    assert main(base + ["--dataset", str(reserved), "--out", str(tmp_path / "a")]) == 2
    assert f"{name} seeds [{seed}]" in capsys.readouterr().err
    assert main(base + ["--dataset", str(clean), "--add-dataset", str(reserved), "--out", str(tmp_path / "b")]) == 2
    assert "never training data" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_data_the_model_was_not_trained_on_is_refused_where_it_must_be(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2], 12, rng)
    other = write_dataset(tmp_path / "other", [1, 2], 12, rng)
    out = tmp_path / "cnn"
    argv = ["--kind", "cnn", "--dataset", str(train), "--out", str(out), "--epochs", "1", "--validation-episodes", "1"]
    argv += ["--checkpoint-dir", str(tmp_path / "checkpoints"), "--threads", "1"]
    assert main(argv) == 0
    result = run_score(out / "policy.toml", other, tmp_path, "--expect", "train")
    assert result.returncode != 0
    assert "a model trained on other data" in result.stderr, result.stderr
    # Without --expect it scores, and says the data is not what the manifest names.
    result = run_score(out / "policy.toml", other, tmp_path)
    assert result.returncode == 0, result.stderr
    assert "data its manifest does not name" in result.stdout
    # The checkpoint of that run does not silently continue on other data.
    argv_other = [a if a != str(train) else str(other) for a in argv]
    assert main(argv_other) == 2
    # A dataset with an episode missing is refused by both sides, naming the episode.
    (other / "episode_00002.npz").unlink()
    result = run_score(out / "policy.toml", other, tmp_path)
    assert result.returncode != 0 and "episode 2 is listed in dataset.json" in result.stderr, result.stderr


def test_a_modal_cnn_answers_the_hypothesis_it_chooses_and_learns_from_the_closest(rng):
    model = ModalCNN(3).eval()
    top = to_input(rng.integers(0, 256, (5, 120, 160), dtype=np.uint8))
    bottom = to_input(rng.integers(0, 256, (5, 60, 80), dtype=np.uint8))
    with torch.no_grad():
        hypotheses, logits = model.forward_all(top, bottom)
        chosen = model(top, bottom)
        assert torch.allclose(chosen, hypotheses[torch.arange(5), logits.argmax(dim=1)])
        # A target equal to hypothesis 1: no error from the winner, a little from the others,
        # and the choice is taught to pick 1.
        target = hypotheses[:, 1].clone()
        errors = ((hypotheses - target[:, None, :]) ** 2).mean(dim=2)
        expected = 0.05 * errors.mean() + 0.1 * torch.nn.functional.cross_entropy(logits, torch.ones(5, dtype=torch.long))
        assert torch.allclose(winner_takes_all_loss(model, top, bottom, target), expected)


def test_the_manifest_names_the_teacher_and_teachers_are_never_mixed(tmp_path, rng):
    paper = write_dataset(tmp_path / "paper", [1, 2], 12, rng)
    observable = write_dataset(tmp_path / "observable", [3, 4], 12, rng)
    index = json.loads((observable / "dataset.json").read_text())
    (observable / "dataset.json").write_text(json.dumps({**index, "teacher": "observable"}))
    base = ["--kind", "cnn", "--epochs", "1", "--validation-episodes", "1", "--threads", "1"]
    out = tmp_path / "cnn"
    argv = base + ["--dataset", str(observable), "--out", str(out), "--checkpoint-dir", str(tmp_path / "c1")]
    assert main(argv) == 0
    assert 'teacher = "observable"' in (out / "policy.toml").read_text()
    # A dataset recorded before there were two teachers is the paper's.
    argv = base + ["--dataset", str(paper), "--out", str(tmp_path / "p"), "--checkpoint-dir", str(tmp_path / "c2")]
    assert main(argv) == 0
    assert 'teacher = "paper"' in (tmp_path / "p" / "policy.toml").read_text()
    # Rows of both teachers, or a test set of the other one, are refused.
    argv = base + ["--dataset", str(paper), "--add-dataset", str(observable), "--out", str(tmp_path / "m"), "--checkpoint-dir", str(tmp_path / "c3")]
    assert main(argv) == 2
    argv = base + ["--dataset", str(paper), "--test-dataset", str(observable), "--out", str(tmp_path / "t"), "--checkpoint-dir", str(tmp_path / "c4")]
    assert main(argv) == 2


def test_an_rcnn_started_from_a_cnns_convolutions_keeps_them_when_frozen(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2, 3], 40, rng)
    test = write_dataset(tmp_path / "test", [10000], 24, rng)
    common = ["--dataset", str(train), "--test-dataset", str(test), "--epochs", "1", "--validation-episodes", "1"]
    common += ["--threads", "1", "--batch-size", "16"]
    assert main(["--kind", "cnn", *common, "--out", str(tmp_path / "cnn"), "--checkpoint-dir", str(tmp_path / "c-cnn")]) == 0
    cnn = torch.load(tmp_path / "c-cnn" / "cnn.pt", weights_only=False)["best"]["state"]
    out = tmp_path / "rcnn"
    argv = ["--kind", "rcnn", *common, "--out", str(out), "--checkpoint-dir", str(tmp_path / "c-rcnn"), "--window", "40", "--lanes", "2"]
    with pytest.raises(SystemExit):
        main(argv + ["--freeze-features"])  # nothing to freeze without --features-from
    # From the shipped CNN's directory (its ONNX weights), as from a checkpoint.
    assert main(argv + ["--features-from", str(tmp_path / "cnn"), "--freeze-features"]) == 0
    rcnn = torch.load(tmp_path / "c-rcnn" / "rcnn.pt", weights_only=False)
    for name, value in rcnn["best"]["state"].items():
        if name.startswith("features."):
            assert torch.equal(value, cnn[name]), name
    assert rcnn["identity"]["freeze_features"] is True
    assert "kept fixed" in (out / "policy.toml").read_text()
    trainer = json.loads((out / "scores.json").read_text())
    result = run_score(out / "policy.toml", test, tmp_path, "--expect", "test", "--json", str(tmp_path / "robot.json"))
    assert result.returncode == 0, result.stdout + result.stderr
    robot = json.loads((tmp_path / "robot.json").read_text())
    assert abs(robot["error"] - trainer["test"]["error"]) < 1e-4


def run_naming_its_start(common: list[str], tmp_path: Path, flags: list[str], note: str, key: str, model: Path) -> list[str]:
    """Trains with `flags` into tmp_path/small and checks that the manifest's notes say `note`
    and the checkpoint's identity names `model` by hash under `key`; returns the arguments."""
    small = tmp_path / "small"
    argv = [*common, *flags, "--out", str(small), "--checkpoint-dir", str(tmp_path / "c-small")]
    assert main(argv) == 0
    assert note in (small / "policy.toml").read_text()
    identity = torch.load(tmp_path / "c-small" / "cnn.pt", weights_only=False)["identity"]
    assert identity[key] == start_sha256(model)
    return argv


def test_a_distilled_cnn_learns_the_shipped_networks_commands_not_the_teachers(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2], 12, rng)
    common = ["--kind", "cnn", "--dataset", str(train), "--epochs", "1", "--validation-episodes", "1", "--threads", "1"]
    # The "shipped" model: a paper-width CNN trained on the teacher's labels.
    big = tmp_path / "big"
    assert main([*common, "--out", str(big), "--checkpoint-dir", str(tmp_path / "c-big")]) == 0
    trainer = Training(parse_args([*common, "--filters", "8,16,4,8", "--out", str(tmp_path / "x"), "--distill-from", str(big)]), ds.load(train))
    # Its labels are what the big network sends for each training row (episode 1: seed 2 is
    # held out), clamped as the controller clamps, and no longer the teacher's.
    rows = Rows.of(trainer.train_episodes)
    net = CNN(PAPER_FILTERS)
    load_shipped_weights(net, big, "cnn")
    with torch.no_grad():
        expected = sent_commands(net.eval()(to_input(rows.top), to_input(rows.bottom)).numpy())
    np.testing.assert_allclose(trainer.rows.command, expected, atol=1e-6)
    assert not np.allclose(trainer.rows.command, rows.command)
    # The run says so, names the model by hash, and resumes only as the same run.
    flags = ["--filters", "8,16,4,8", "--distill-from", str(big)]
    run_naming_its_start(common, tmp_path, flags, "distilled: trained on the commands of", "distill_from", big)
    # Not a model to distil from, or not a kind that can be: refused with a reason.
    assert main([*common, "--out", str(tmp_path / "y"), "--checkpoint-dir", str(tmp_path / "c-y"), "--distill-from", str(train)]) == 2
    assert main(["--kind", "hcnn", *common[2:], "--out", str(tmp_path / "z"), "--checkpoint-dir", str(tmp_path / "c-z"), "--distill-from", str(big)]) == 2


def test_distilling_where_the_camera_is_clean_keeps_the_teachers_labels_elsewhere(tmp_path, rng):
    train, common, big = conditioned_data_and_model(tmp_path, rng, [1, 2, 3], ["robots:2", "contrast:3,robots:1", "clean"])
    flags = ["--distill-from", str(big), "--distill-camera-clean"]
    trainer = Training(parse_args([*common, "--out", str(tmp_path / "x"), *flags]), ds.load(train))
    # Seed 1 (robots only) takes the model's commands; seed 2 (contrast) keeps the teacher's;
    # seed 3 is held out.
    assert [e.conditions for e in trainer.train_episodes] == ["robots:2", "contrast:3,robots:1"]
    teacher = Rows.of(trainer.train_episodes).command
    net = CNN(PAPER_FILTERS)
    load_shipped_weights(net, big, "cnn")
    with torch.no_grad():
        first = trainer.train_episodes[0]
        expected = sent_commands(net.eval()(to_input(first.top), to_input(first.bottom)).numpy())
    np.testing.assert_allclose(trainer.rows.command[:6], expected, atol=1e-6)
    np.testing.assert_array_equal(trainer.rows.command[6:], teacher[6:])
    assert "on the rows of camera-clean episodes" in notes_of(parse_args([*common, "--out", "o", *flags]))
    # Without a model to take commands from, the flag means nothing: refused.
    with pytest.raises(SystemExit):
        parse_args([*common, "--out", "o", "--distill-camera-clean"])


def test_conditioned_rows_with_a_clean_twin_take_the_models_commands_on_the_twin(tmp_path, rng):
    train, common, big = conditioned_data_and_model(tmp_path, rng, [1, 2, 3, 4], ["clean", "contrast:3", "noise:2", "clean"], twinned=(2,))
    flags = ["--distill-from", str(big), "--distill-camera-clean"]
    trainer = Training(parse_args([*common, "--out", str(tmp_path / "x"), *flags]), ds.load(train))
    clean, twinned, untwinned = trainer.train_episodes
    assert (clean.has_clean_twin, twinned.has_clean_twin, untwinned.has_clean_twin) == (False, True, False)
    net = CNN(PAPER_FILTERS)
    load_shipped_weights(net, big, "cnn")

    def sent(top, bottom):
        with torch.no_grad():
            return sent_commands(net.eval()(to_input(top), to_input(bottom)).numpy())

    # Seed 1 (clean): the model on its own images; seed 2 (contrast, twinned): the model on
    # the twin's images, not on the conditioned ones; seed 3 (noise, no twin): the teacher's.
    np.testing.assert_allclose(trainer.rows.command[:6], sent(clean.top, clean.bottom), atol=1e-6)
    np.testing.assert_allclose(trainer.rows.command[6:12], sent(twinned.top_clean, twinned.bottom_clean), atol=1e-6)
    assert not np.allclose(trainer.rows.command[6:12], sent(twinned.top, twinned.bottom), atol=1e-3)
    np.testing.assert_array_equal(trainer.rows.command[12:], untwinned.command)
    # A piece of an episode (a stall cut) keeps its twin's rows.
    piece = twinned.rows(2, 5)
    np.testing.assert_array_equal(piece.top_clean, twinned.top_clean[2:5])
    np.testing.assert_array_equal(piece.bottom_clean, twinned.bottom_clean[2:5])


def test_a_clean_twin_that_does_not_hold_the_rows_is_refused(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1], 4, rng)
    with np.load(train / "episode_00001.npz") as arrays:
        kept = {name: arrays[name] for name in arrays.files}
    np.savez_compressed(train / "episode_00001.npz", **kept, top_clean=kept["top"][:3], bottom_clean=kept["bottom"][:3])
    index = json.loads((train / "dataset.json").read_text())
    index["episodes"][0]["sha256"] = hashlib.sha256((train / "episode_00001.npz").read_bytes()).hexdigest()
    index["content_hash"] = ds.content_hash(index["episodes"])
    (train / "dataset.json").write_text(json.dumps(index))
    with pytest.raises(ds.DatasetError, match="clean twin"):
        ds.load(train)


def test_the_one_way_detour_relabels_the_teachers_detour_rows_and_outlasts_distillation(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2, 3], 6, rng)
    index = json.loads((train / "dataset.json").read_text())
    rule = OneWayDetour()
    # Seed 1's first two rows: the teacher going around a ball at (1, 0) from its goal side.
    poses = np.array([[1.0, -0.3, np.pi / 2], [1.05, -0.28, np.pi / 2 + 0.1]])
    ball = np.array([1.0, 0.0])
    entry = index["episodes"][0]
    with np.load(train / entry["file"]) as arrays:
        episode = dict(arrays)
    for i, pose in enumerate(poses):
        episode["robot_pose"][i], episode["ball"][i], episode["phase"][i] = pose, ball, 1
        episode["command"][i] = rule.command(pose, ball, 1.0, one_way=False)[0]
    episode["ball"][2:] = ball
    np.savez_compressed(train / entry["file"], **episode)
    entry["sha256"] = hashlib.sha256((train / entry["file"]).read_bytes()).hexdigest()
    entry["conditions"] = "clean"
    index["content_hash"] = ds.content_hash(index["episodes"])
    (train / "dataset.json").write_text(json.dumps(index))
    common = ["--kind", "cnn", "--dataset", str(train), "--epochs", "1", "--validation-episodes", "1", "--threads", "1"]
    # The paper teacher's rows are not the detector's: refused.
    assert main([*common, "--out", str(tmp_path / "p"), "--checkpoint-dir", str(tmp_path / "c-p"), "--one-way-detour"]) == 2
    index["teacher"] = "detector"
    (train / "dataset.json").write_text(json.dumps(index))
    big = tmp_path / "big"
    assert main([*common, "--out", str(big), "--checkpoint-dir", str(tmp_path / "c-big")]) == 0
    flags = ["--distill-from", str(big), "--distill-camera-clean", "--one-way-detour"]
    trainer = Training(parse_args([*common, "--out", str(tmp_path / "x"), *flags]), ds.load(train))
    one_way = np.array([rule.command(pose, ball, 1.0, one_way=True)[0] for pose in poses], np.float32)
    # The detour rows keep their one-way labels; the rest of the clean episode is distilled.
    np.testing.assert_allclose(trainer.rows.command[:2], one_way, atol=1e-6)
    assert np.abs(trainer.rows.command[2:6] - episode["command"][2:6]).max() > 1e-3
    np.testing.assert_allclose(trainer.train_episodes[0].command[:2], one_way, atol=1e-6)
    assert "relabelled to go one way" in notes_of(parse_args([*common, "--out", "o", *flags]))
    one_way_model = tmp_path / "one-way"
    assert main([*common, "--out", str(one_way_model), "--checkpoint-dir", str(tmp_path / "c-o"), "--one-way-detour"]) == 0
    assert 'teacher = "detector-one-way"' in (one_way_model / "policy.toml").read_text()


def test_the_detour_at_the_ball_is_sampled_more_often_and_keeps_the_teachers_labels(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2, 3], 6, rng)
    index = json.loads((train / "dataset.json").read_text())
    rule = OneWayDetour()
    # Seed 1: the teacher going around a ball at (1, 0) from its goal side, at the ball
    # (0.25 m) on row 0, half a metre away on row 1.
    poses = np.array([[1.0, -0.25, np.pi / 2], [1.05, -0.5, np.pi / 2]])
    ball = np.array([1.0, 0.0])
    entry = index["episodes"][0]
    with np.load(train / entry["file"]) as arrays:
        episode = dict(arrays)
    episode["ball"][:] = ball
    episode["robot_pose"][2:] = [-2.0, 0.0, 0.0]
    for i, pose in enumerate(poses):
        episode["robot_pose"][i], episode["phase"][i] = pose, 1
        episode["command"][i] = rule.command(pose, ball, 1.0, one_way=False)[0]
    np.savez_compressed(train / entry["file"], **episode)
    entry["sha256"] = hashlib.sha256((train / entry["file"]).read_bytes()).hexdigest()
    entry["conditions"] = "clean"
    index["content_hash"] = ds.content_hash(index["episodes"])
    index["teacher"] = "detector"
    (train / "dataset.json").write_text(json.dumps(index))
    common = ["--kind", "cnn", "--dataset", str(train), "--epochs", "1", "--validation-episodes", "1", "--threads", "1"]
    big = tmp_path / "big"
    assert main([*common, "--out", str(big), "--checkpoint-dir", str(tmp_path / "c-big")]) == 0
    flags = ["--distill-from", str(big), "--distill-camera-clean", "--detour-weight", "50"]
    trainer = Training(parse_args([*common, "--out", str(tmp_path / "x"), *flags]), ds.load(train))
    assert list(trainer.at_ball) == [True] + [False] * 11
    # The row at the ball keeps the teacher's label; the detour row away from it is distilled.
    np.testing.assert_allclose(trainer.rows.command[0], episode["command"][0], atol=1e-6)
    assert np.abs(trainer.rows.command[1] - episode["command"][1]).max() > 1e-3
    drawn = np.concatenate([b for _, b in trainer.epoch_rows(np.random.default_rng(0))])
    # Weight 50 among 12 rows: about 50 / 61 of the draws, against 1 / 12 uniformly.
    assert (drawn == 0).mean() > 0.5
    plain = Training(parse_args([*common, "--out", str(tmp_path / "y")]), ds.load(train))
    assert len(plain.at_ball) == 0
    assert "detour rows at the ball" in notes_of(parse_args([*common, "--out", "o", *flags]))
    for refused in (["--detour-weight", "0"], ["--detour-weight", "2", "--one-way-detour"]):
        with pytest.raises(SystemExit):
            parse_args([*common, "--out", "o", *refused])


def test_a_pruned_start_takes_the_wide_models_strongest_filters(tmp_path, rng):
    train = write_dataset(tmp_path / "train", [1, 2], 12, rng)
    common = ["--kind", "cnn", "--dataset", str(train), "--epochs", "1", "--validation-episodes", "1", "--threads", "1"]
    big = tmp_path / "big"
    assert main([*common, "--filters", "8,16,4,8", "--out", str(big), "--checkpoint-dir", str(tmp_path / "c-big")]) == 0
    argv = [*common, "--filters", "4,16,4,8", "--out", str(tmp_path / "x"), "--prune-from", str(big)]
    trainer = Training(parse_args(argv), ds.load(train))
    expected = CNN(Filters(4, 16, 4, 8))
    load_pruned_weights(expected, big)
    for name, value in expected.state_dict().items():
        assert torch.equal(trainer.model.state_dict()[name].cpu(), value), name
    # The run names its start by hash, in the manifest and the checkpoint.
    flags = ["--filters", "4,16,4,8", "--prune-from", str(big)]
    argv = run_naming_its_start(common, tmp_path, flags, "pruned to these filters", "prune_from", big)
    # Wider than its start, or two starts at once: refused.
    assert main([*common, "--out", str(tmp_path / "y"), "--checkpoint-dir", str(tmp_path / "c-y"), "--prune-from", str(big)]) == 2
    with pytest.raises(SystemExit):
        parse_args([*argv, "--init-from", str(big)])


def test_the_notes_say_who_drove_each_added_dataset(tmp_path, rng):
    demonstrations = write_dataset(tmp_path / "more-0", [100], 4, rng)
    round_ = write_dataset(tmp_path / "round-1", [1000], 4, rng)
    index = json.loads((round_ / "dataset.json").read_text())
    (round_ / "dataset.json").write_text(json.dumps({**index, "driver": {"policy": "p/policy.toml", "beta": 0.5}}))
    args = parse_args(["--kind", "cnn", "--dataset", str(demonstrations), "--out", str(tmp_path / "x"),
                       "--add-dataset", str(demonstrations), "--add-dataset", str(round_)])
    assert "plus every episode of more-0 (expert-driven), round-1 (policy-driven) (expert-labelled)" in notes_of(args)


def test_camera_augmentation_changes_a_share_of_the_rows_within_range_and_follows_the_seed():
    generator = torch.Generator().manual_seed(3)
    top, bottom = torch.rand(64, 1, 120, 160, generator=generator), torch.rand(64, 1, 60, 80, generator=generator)
    augment = CameraAugment(share=0.5)
    first = augment(top, bottom, torch.Generator().manual_seed(7))
    again = augment(top, bottom, torch.Generator().manual_seed(7))
    assert all(torch.equal(a, b) for a, b in zip(first, again))
    for augmented in first:
        assert augmented.min() >= 0.0 and augmented.max() <= 1.0
    changed = (first[0] - top).abs().flatten(1).amax(1) > 1e-5
    assert 16 <= int(changed.sum()) <= 48, int(changed.sum())
    untouched = CameraAugment(share=0.0)(top, bottom, torch.Generator().manual_seed(7))
    # Without a share, only the round trip through the sensor's curve remains.
    assert torch.allclose(untouched[0], top, atol=1e-5) and torch.allclose(untouched[1], bottom, atol=1e-5)


def test_strong_camera_augmentation_reaches_lower_contrast_than_the_standard():
    generator = torch.Generator().manual_seed(3)
    top, bottom = torch.rand(256, 1, 120, 160, generator=generator), torch.rand(256, 1, 60, 80, generator=generator)

    def lowest_spread(augment: CameraAugment) -> float:
        out, _ = augment(top, bottom, torch.Generator().manual_seed(5))
        return float((out.flatten(1).std(1) / top.flatten(1).std(1)).min())

    standard, strong = CameraAugment.of_strength(1.0, "standard"), CameraAugment.of_strength(1.0, "strong")
    assert strong.contrast_low < standard.contrast_low and strong.effect_chance > standard.effect_chance
    assert lowest_spread(strong) < lowest_spread(standard)


def test_a_camera_turn_smears_along_its_direction_and_skews_the_lower_rows():
    image = torch.zeros(3, 1, 40, 60)
    image[:, :, 20, 30] = 1.0  # one bright point
    image[:, :, :, 10] = 1.0  # one bright column
    motion = CameraMotion(torch.tensor([8.0, 8.0, 0.0]), torch.tensor([0.0, torch.pi / 2, 0.0]), torch.tensor([0.0, 0.0, 6.0]))
    out = motion.smear(image)
    along_x, along_y, skewed = out[0, 0], out[1, 0], out[2, 0]
    # A turn spreads the point along its row only; a nod along its column only.
    assert along_x[20, 26:35].min() > 0.05 and along_x[19, 25:36].abs().max() < 1e-6
    assert along_y[16:25, 30].min() > 0.05 and along_y[16:25, 29].abs().max() < 1e-6
    # The column, sharp under the skew, leans: its top row moves 3 pixels one way, its bottom 3 the other.
    assert int(skewed[0].argmax()) == 13 and int(skewed[-1].argmax()) == 7 and int(skewed[20].argmax()) == 10
    assert torch.equal(CameraMotion(torch.zeros(3), torch.zeros(3), torch.zeros(3)).smear(image), image)


def test_light_patches_darken_and_brighten_within_their_ranges_and_leave_other_rows_alone():
    generator = torch.Generator().manual_seed(11)
    chance = torch.tensor([1.0] * 63 + [0.0]).view(64, 1, 1, 1)
    gains = light_patches(64, (60, 80), generator, chance)
    assert gains.shape == (64, 1, 60, 80)
    assert float(gains[:63].min()) < 0.6 and float(gains[:63].max()) > 1.5
    assert float(gains.min()) >= 0.4**3 - 1e-6 and float(gains.max()) <= 1.9**3 + 1e-6
    assert torch.equal(gains[63], torch.ones(1, 60, 80))


def test_motion_and_light_augmentation_follows_the_seed_and_moves_both_cameras_alike():
    generator = torch.Generator().manual_seed(3)
    top, bottom = torch.rand(64, 1, 120, 160, generator=generator), torch.rand(64, 1, 60, 80, generator=generator)
    augment = CameraAugment.of_strength(0.5, "motion-and-light")
    first = augment(top, bottom, torch.Generator().manual_seed(7))
    again = augment(top, bottom, torch.Generator().manual_seed(7))
    assert all(torch.equal(a, b) for a, b in zip(first, again))
    for augmented in first:
        assert augmented.min() >= 0.0 and augmented.max() <= 1.0
    length, _, skew = augment.turn(1000, torch.ones(1000, 1, 1, 1), torch.Generator().manual_seed(1))
    moving = length > 0
    assert 300 < int(moving.sum()) < 500 and float(length.max()) <= 8.0 and float(skew.abs().max()) <= 6.0
    standard = CameraAugment.of_strength(0.5, "standard")
    assert standard.motion_share == 0.0 and standard.patch_chance == 0.0


def test_camera_augmentation_is_named_in_the_notes():
    args = parse_args(["--kind", "cnn", "--dataset", "d", "--out", "o", "--camera-augment", "0.5"])
    assert "camera conditions augmented on 50% of the rows" in notes_of(args, torch.device("cpu"))
    strong = parse_args(["--kind", "cnn", "--dataset", "d", "--out", "o", "--camera-augment", "0.5", "--camera-augment-strength", "strong"])
    assert "noise, strong ranges)" in notes_of(strong)
    moving = parse_args(["--kind", "cnn", "--dataset", "d", "--out", "o", "--camera-augment", "0.5", "--camera-augment-strength", "motion-and-light"])
    assert "the camera's turn (directional smear, rolling-shutter skew), patches of shadow and sunlight" in notes_of(moving)
    with pytest.raises(SystemExit):
        parse_args(["--kind", "cnn", "--dataset", "d", "--out", "o", "--camera-augment", "2"])


def test_the_options_become_a_typed_frozen_configuration():
    from dataclasses import FrozenInstanceError

    from dribble_models.train import TrainingConfig

    config = parse_args(["--kind", "rcnn", "--dataset", "d", "--out", "o", "--add-dataset", "a", "--add-dataset", "b"])
    assert isinstance(config, TrainingConfig)
    assert config.epochs > 0 and config.add_dataset == (Path("a"), Path("b")) and config.window == 100
    with pytest.raises(FrozenInstanceError):
        config.lr = 1.0  # type: ignore[misc]


def test_a_folded_start_answers_as_before_on_a_typical_thumbnail(rng):
    """`fold_typical_level` re-expresses a `pixel / 255` model's first layers for standardised
    input: on thumbnails whose own mean and spread are the rows' typical ones, the folded,
    standardising model's first convolution answers as the old one did (away from the
    zero-padded border, where the two paddings differ)."""
    from dribble_models.networks import set_standardise
    from dribble_models.networks import standardised
    from dribble_models.standardised_start import fold_typical_level
    from dribble_models.train import Rows

    def rows_like(top_base, bottom_base, n=6):
        # Every row the same pattern: its mean and spread are the typical ones.
        return Rows(
            top=np.repeat(top_base[None], n, axis=0),
            bottom=np.repeat(bottom_base[None], n, axis=0),
            command=np.zeros((n, 3), np.float32),
            phase=np.zeros(n, np.uint8),
            previous=np.zeros((n, 3), np.float32),
            mirrorable=np.ones(n, bool),
        )

    top = rng.integers(40, 200, (120, 160), dtype=np.uint8)
    bottom = rng.integers(60, 220, (60, 80), dtype=np.uint8)
    old = CNN(Filters(4, 8, 4, 8)).eval()
    new = CNN(Filters(4, 8, 4, 8)).eval()
    new.load_state_dict(old.state_dict())
    fold_typical_level(new, rows_like(top, bottom), np.random.default_rng(0))
    set_standardise(new, True)
    scaled = torch.from_numpy(top[None, None].astype(np.float32) / 255)
    with torch.no_grad():
        before = old.features.top[0](scaled)[..., 2:-2, 2:-2]
        after = new.features.top[0](standardised(scaled))[..., 2:-2, 2:-2]
    assert torch.allclose(before, after, atol=1e-4), float((before - after).abs().max())
    assert not torch.allclose(old.features.top[0].weight, new.features.top[0].weight)


def test_validating_on_the_distilled_commands_gives_the_held_out_episodes_those_labels(tmp_path, rng):
    train, common, big = conditioned_data_and_model(tmp_path, rng, [1, 2, 3], ["clean", "clean", "contrast:3"], twinned=(3,))
    flags = ["--distill-from", str(big), "--distill-camera-clean"]
    held = ds.load(train).episodes[2]
    plain = Training(parse_args([*common, "--out", str(tmp_path / "x"), *flags]), ds.load(train))
    np.testing.assert_array_equal(plain.validation_episodes[0].command, held.command)
    trainer = Training(parse_args([*common, "--out", str(tmp_path / "y"), *flags, "--validate-distilled"]), ds.load(train))
    net = CNN(PAPER_FILTERS)
    load_shipped_weights(net, big, "cnn")
    with torch.no_grad():
        expected = sent_commands(net.eval()(to_input(held.top_clean), to_input(held.bottom_clean)).numpy())
    np.testing.assert_allclose(trainer.validation_episodes[0].command, expected, atol=1e-6)
    assert "validated on them by the same rule" in notes_of(parse_args([*common, "--out", "o", *flags, "--validate-distilled"]))
    with pytest.raises(SystemExit):
        parse_args([*common, "--out", "o", "--validate-distilled"])


def test_a_cnn_reading_its_last_command_is_given_what_was_executed_before_each_row(tmp_path, rng):
    """In a policy-driven round the robot executed the policy's command, or the expert's where
    DAgger's draw chose it: the trainer and the robot's scorer feed each row the command
    executed at the row before, clamped, a stop at the first."""
    data = write_dataset(tmp_path / "round", [1, 2, 3], 12, rng, driven=True)
    episode = ds.load(data).episodes[0]
    with np.load(data / "episode_00001.npz") as arrays:
        executed = np.where(arrays["expert_executed"][:, None] == 1, arrays["command"], arrays["policy_command"])
    assert np.array_equal(episode.previous[0], np.zeros(3, np.float32))
    assert np.array_equal(episode.previous[1:], np.clip(executed[:-1], -1, 1).astype(np.float32))
    # A piece of an episode (a stall cut) keeps what was executed before its rows.
    assert np.array_equal(episode.rows(4, 8).previous, episode.previous[4:8])
    out = tmp_path / "model"
    argv = ["--kind", "cnn", "--previous-command", "--dataset", str(data), "--out", str(out), "--epochs", "1"]
    argv += ["--validation-episodes", "1", "--batch-size", "8", "--checkpoint-dir", str(tmp_path / "checkpoints"), "--threads", "1"]
    assert main(argv) == 0
    assert "previous = { name = \"previous\", shape = [1, 3] }" in (out / "policy.toml").read_text()
    trainer = json.loads((out / "scores.json").read_text())["train"]
    result = run_score(out / "policy.toml", data, tmp_path, "--json", str(tmp_path / "score.json"))
    assert result.returncode == 0, result.stdout + result.stderr
    robot = json.loads((tmp_path / "score.json").read_text())
    assert abs(robot["error"] - trainer["error"]) < 1e-4, (robot["error"], trainer["error"])
    with pytest.raises(SystemExit):
        parse_args(["--kind", "rcnn", "--previous-command", "--dataset", str(data), "--out", str(out)])


def test_the_last_command_is_perturbed_and_dropped_on_training_rows_as_asked(tmp_path, rng):
    data = write_dataset(tmp_path / "train", [1, 2], 40, rng)
    common = ["--kind", "cnn", "--previous-command", "--dataset", str(data), "--out", str(tmp_path / "x"), "--validation-episodes", "1"]
    index = np.arange(40)
    exact = Training(parse_args([*common, "--previous-noise", "0"]), ds.load(data))
    np.testing.assert_array_equal(exact.batch_previous(index, torch.Generator().manual_seed(0)).numpy(), exact.rows.previous[index])
    dropped = Training(parse_args([*common, "--previous-noise", "0", "--previous-dropout", "0.5"]), ds.load(data))
    given = dropped.batch_previous(index, torch.Generator().manual_seed(0)).numpy()
    stops = np.all(given == 0, axis=1) & np.any(dropped.rows.previous[index] != 0, axis=1)
    kept = np.all(given == dropped.rows.previous[index], axis=1)
    assert np.all(stops | kept) and 8 < stops.sum() < 32, stops.sum()
    noisy = Training(parse_args(common), ds.load(data)).batch_previous(index, torch.Generator().manual_seed(0)).numpy()
    assert 0.1 < np.std(noisy - exact.rows.previous[index]) < 0.3  # the default noise, 0.2
    assert "a stop in its place on 50% of them" in notes_of(parse_args([*common, "--previous-dropout", "0.5"]))
    with pytest.raises(SystemExit):
        parse_args(["--kind", "cnn", "--previous-dropout", "0.5", "--dataset", str(data), "--out", "o"])
    # Narrowed to the teacher's search phase: every search row there gets the stop, no other row.
    narrowed = [*common, "--previous-noise", "0", "--previous-dropout", "1", "--previous-dropout-phases", "search"]
    searching = Training(parse_args(narrowed), ds.load(data))
    given = searching.batch_previous(index, torch.Generator().manual_seed(0)).numpy()
    search = searching.rows.phase[index] == 0
    assert 0 < search.sum() < len(index)
    np.testing.assert_array_equal(given[search], 0)
    np.testing.assert_array_equal(given[~search], searching.rows.previous[index][~search])
    assert "a stop in its place on 100% of them in the teacher's search phase" in notes_of(parse_args(narrowed))
    for wrong in (["--previous-dropout-phases", "search"], ["--previous-dropout", "0.5", "--previous-dropout-phases", "walking"]):
        with pytest.raises(SystemExit):
            parse_args([*common, *wrong])


def test_the_last_command_fades_toward_a_stop_on_the_share_asked(tmp_path, rng):
    """`--previous-shrink`: on its share of the rows the last command is scaled by a factor in
    [0, 1), each component by the same one (its direction kept); the other rows keep theirs."""
    data = write_dataset(tmp_path / "train", [1, 2], 40, rng)
    common = ["--kind", "cnn", "--previous-command", "--dataset", str(data), "--out", str(tmp_path / "x"), "--validation-episodes", "1"]
    index = np.arange(40)
    faded = Training(parse_args([*common, "--previous-noise", "0", "--previous-shrink", "0.5"]), ds.load(data))
    given = faded.batch_previous(index, torch.Generator().manual_seed(0)).numpy()
    sent = faded.rows.previous[index]
    moving = np.linalg.norm(sent, axis=1) > 1e-3
    assert moving.sum() > 20
    ratio = np.linalg.norm(given, axis=1)[moving] / np.linalg.norm(sent, axis=1)[moving]
    kept = np.isclose(ratio, 1.0)
    assert np.all(ratio < 1.0 + 1e-6) and 5 < (~kept).sum() < moving.sum() - 5, ratio
    # The same factor on every component: the faded command points where the sent one did.
    cosine = np.sum(given[moving] * sent[moving], axis=1) / (np.linalg.norm(given[moving], axis=1) * np.linalg.norm(sent[moving], axis=1) + 1e-12)
    assert np.all(cosine[ratio > 1e-3] > 0.9999), cosine
    # Every row faded at share 1, the same draws for the same generator seed.
    every = Training(parse_args([*common, "--previous-noise", "0", "--previous-shrink", "1"]), ds.load(data))
    first = every.batch_previous(index, torch.Generator().manual_seed(3)).numpy()
    np.testing.assert_array_equal(first, every.batch_previous(index, torch.Generator().manual_seed(3)).numpy())
    assert np.all(np.linalg.norm(first, axis=1)[moving] < np.linalg.norm(sent, axis=1)[moving])
    record = Training(parse_args([*common, "--previous-shrink", "0.3"]), ds.load(data)).identity()["previous_command"]
    assert record == {"noise": 0.2, "shrink": 0.3}
    assert "faded toward a stop" in notes_of(parse_args([*common, "--previous-shrink", "0.3"]))
    assert "faded" not in notes_of(parse_args(common))
    for wrong in (["--previous-shrink", "1.5"], ["--previous-shrink", "-0.1"]):
        with pytest.raises(SystemExit):
            parse_args([*common, *wrong])
    with pytest.raises(SystemExit):
        parse_args(["--kind", "cnn", "--previous-shrink", "0.3", "--dataset", str(data), "--out", "o"])


def test_the_first_search_is_never_mirrored_and_every_later_row_may_be():
    """`mirrorable`: the teacher turns left by convention until it first sees the ball, so the
    search rows before an episode's first sighting have no mirror row; the rest have."""
    search, approach, align = (ds.PHASES.index(p) for p in ("search", "approach", "align"))
    phases = np.array([search, search, search, approach, align, search, search, approach], np.uint8)
    np.testing.assert_array_equal(mirrorable(phases), [False, False, False, True, True, True, True, True])
    np.testing.assert_array_equal(mirrorable(np.array([approach, search], np.uint8)), [True, True])
    assert not mirrorable(np.full(5, search, np.uint8)).any()
    assert mirrorable(np.zeros(0, np.uint8)).shape == (0,)


def test_a_mirrored_row_is_its_mirror_states_row(rng):
    """`mirrored`: a chosen row's thumbnails flipped left to right, its command's and last
    command's sideways and turn negated, forward kept; rows not chosen or not allowed as they
    were; the same draws for the same generator seed, about the share asked for."""
    n = 400
    top = torch.rand(n, 1, 120, 160)
    bottom = torch.rand(n, 1, 60, 80)
    command = torch.from_numpy(rng.uniform(-1, 1, (n, 3)).astype(np.float32))
    previous = torch.from_numpy(rng.uniform(-1, 1, (n, 3)).astype(np.float32))
    allowed = torch.ones(n, dtype=torch.bool)
    allowed[:50] = False
    t, b, c, p = mirrored(0.5, torch.Generator().manual_seed(7), allowed, top, bottom, command, previous)
    flipped = (c[:, 1] != command[:, 1])
    assert not flipped[:50].any()
    assert 140 < int(flipped.sum()) < 210, int(flipped.sum())
    assert torch.equal(t[flipped], top[flipped].flip(-1)) and torch.equal(b[flipped], bottom[flipped].flip(-1))
    assert torch.equal(t[~flipped], top[~flipped]) and torch.equal(b[~flipped], bottom[~flipped])
    for given, original in ((c, command), (p, previous)):
        assert torch.equal(given[:, 0], original[:, 0])
        assert torch.equal(given[flipped][:, 1:], -original[flipped][:, 1:])
        assert torch.equal(given[~flipped], original[~flipped])
    again = mirrored(0.5, torch.Generator().manual_seed(7), allowed, top, bottom, command, previous)
    assert all(torch.equal(x, y) for x, y in zip(again, (t, b, c, p)))
    # Twice mirrored is the row itself; without a last command there is none to mirror.
    twice = mirrored(1.0, torch.Generator(), torch.ones(n, dtype=torch.bool), *mirrored(1.0, torch.Generator(), torch.ones(n, dtype=torch.bool), top, bottom, command)[:3])
    assert torch.equal(twice[0], top) and torch.equal(twice[2], command) and twice[3] is None


def test_mirroring_is_asked_for_a_one_output_cnn_and_named_where_it_was_used(tmp_path, rng):
    """`--mirror SHARE`: in the checkpoint's identity and the notes where set (not otherwise,
    so older checkpoints resume), the training rows know which are mirrorable, and what it
    cannot serve is refused."""
    data = write_dataset(tmp_path / "train", [1, 2], 40, rng)
    common = ["--kind", "cnn", "--previous-command", "--dataset", str(data), "--out", str(tmp_path / "x"), "--validation-episodes", "1"]
    trainer = Training(parse_args([*common, "--mirror", "0.5"]), ds.load(data))
    assert trainer.identity()["mirror"] == 0.5
    assert "mirror" not in Training(parse_args(common), ds.load(data)).identity()
    np.testing.assert_array_equal(trainer.rows.mirrorable, mirrorable(trainer.train_episodes[0].phase))
    assert "mirrored left to right" in notes_of(parse_args([*common, "--mirror", "0.5"]))
    assert "mirrored" not in notes_of(parse_args(common))
    for wrong in (["--mirror", "1.5"], ["--mirror", "-0.1"], ["--mirror", "0.5", "--one-way-detour"], ["--mirror", "0.5", "--modes", "2"]):
        with pytest.raises(SystemExit):
            parse_args([*common, *wrong])
    with pytest.raises(SystemExit):
        parse_args(["--kind", "rcnn", "--mirror", "0.5", "--dataset", str(data), "--out", "o"])


def test_kept_branches_stay_the_starts_while_the_dense_layers_learn(tmp_path, rng):
    """`--keep-branches`: a CNN started from another keeps its camera branches bit for bit
    (with the last command as a new input too) and trains only its dense layers."""
    data = write_dataset(tmp_path / "train", [1, 2, 3], 24, rng)
    common = ["--dataset", str(data), "--epochs", "1", "--validation-episodes", "1", "--threads", "1", "--batch-size", "8"]
    start = tmp_path / "start"
    assert main(["--kind", "cnn", *common, "--out", str(start), "--checkpoint-dir", str(tmp_path / "c-start")]) == 0
    started = torch.load(tmp_path / "c-start" / "cnn.pt", weights_only=False)["best"]["state"]
    out = tmp_path / "kept"
    argv = ["--kind", "cnn", *common, "--init-from", str(start), "--keep-branches", "--previous-command"]
    assert main([*argv, "--out", str(out), "--checkpoint-dir", str(tmp_path / "c-kept"), "--lr", "1e-2"]) == 0
    checkpoint = torch.load(tmp_path / "c-kept" / "cnn.pt", weights_only=False)
    state = checkpoint["best"]["state"]  # after its one epoch
    branches = [name for name in started if name.startswith("features.")]
    assert branches
    for name in branches:
        assert torch.equal(state[name], started[name]), name
    assert not torch.equal(state["out.weight"], started["head.2.weight"]), "the head learned"
    assert checkpoint["identity"]["keep_branches"] is True
    manifest = (out / "policy.toml").read_text()
    assert "camera branches kept as they are" in manifest
    for refused in (["--kind", "cnn", "--keep-branches"], ["--kind", "rcnn", "--init-from", str(start), "--keep-branches"]):
        with pytest.raises(SystemExit):
            parse_args([*refused, "--dataset", str(data), "--out", str(out)])
