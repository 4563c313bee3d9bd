"""DAgger end to end at toy scale: `scripts/dagger --tiny` with one iteration of two
policy-driven episodes records expert-labelled rows, trains on them from the base's weights,
scores, evaluates in closed loop and reports. No test here asserts how well anything learns."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from dribble_models.train import main as train_main

from test_train import write_dataset

REPOSITORY = Path(__file__).resolve().parents[2]


def test_malformed_episode_counts_and_run_names_are_refused_before_anything_runs():
    for arguments in (["--episodes", "2,x"], ["--episodes", "0"], ["--episodes", "2,,3"], ["--name", "../elsewhere"]):
        result = subprocess.run([str(REPOSITORY / "scripts" / "dagger"), *arguments], capture_output=True, text=True, timeout=60)
        assert result.returncode == 2, (arguments, result.stdout, result.stderr)
        assert "scripts/dagger: --" in result.stderr, (arguments, result.stderr)


def test_one_tiny_dagger_iteration_runs_the_whole_loop(tmp_path, rng):
    data = tmp_path / "data"
    write_dataset(data / "train", [1, 2, 3], 16, rng)
    write_dataset(data / "test", [10000], 16, rng)
    base = tmp_path / "models" / "base"
    checkpoints = tmp_path / "checkpoints"
    argv = ["--kind", "cnn", "--dataset", str(data / "train"), "--test-dataset", str(data / "test"), "--out", str(base)]
    argv += ["--epochs", "1", "--validation-episodes", "1", "--batch-size", "16", "--threads", "1"]
    argv += ["--checkpoint-dir", str(checkpoints / "base")]
    assert train_main(argv) == 0
    environment = dict(
        os.environ,
        DRIBBLE_DATA=str(data),
        DRIBBLE_DAGGER_DIR=str(tmp_path / "dagger"),
        DRIBBLE_CHECKPOINTS=str(checkpoints),
        DRIBBLE_DOMAIN=f"dribble-dagger-test-{os.getpid()}",
    )
    command = [str(REPOSITORY / "scripts" / "dagger"), "--base", str(base), "--iterations", "1", "--episodes", "2,5", "--tiny"]
    # A named run; the first iteration takes the first of the per-iteration counts.
    command += ["--name", "tiny-run"]
    result = subprocess.run(command, env=environment, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]

    # The round: two policy-driven episodes on fresh seeds, labelled by the expert.
    round_dir = data / "dagger" / "tiny-run" / "round-1"
    index = json.loads((round_dir / "dataset.json").read_text())
    assert [e["seed"] for e in index["episodes"]] == [1000, 1001]
    assert index["driver"]["label_with"] == "expert"
    assert index["driver"]["beta"] == 0.5
    assert index["driver"]["policy"].endswith("base/policy.toml")
    with np.load(round_dir / "episode_01000.npz") as arrays:
        rows = len(arrays["phase"])
        assert arrays["policy_command"].shape == (rows, 3)
        assert arrays["expert_executed"].shape == (rows,)
        assert rows == index["episodes"][0]["rows"] > 0

    # The retrained model names every dataset it learned from and was scored and evaluated.
    model = tmp_path / "dagger" / "tiny-run" / "iter-1"
    manifest = (model / "policy.toml").read_text()
    assert 'name = "round-1"' in manifest and index["content_hash"] in manifest
    assert "started from the kept weights of" in manifest
    assert "stalls in them cut after 3 s" in manifest
    # The only iteration is the chosen one: it alone is evaluated on the test seeds.
    assert (tmp_path / "dagger" / "tiny-run" / "CHOSEN").read_text().strip() == str(model)
    assert [e["seed"] for e in json.loads((model / "select.json").read_text())["episodes"]] == [20000]
    assert [e["seed"] for e in json.loads((model / "fresh.json").read_text())["episodes"]] == [30000]
    for name in ("score_test.json", "eval.json", "fresh.json", "select.json", "eval_trajectories.png"):
        assert (model / name).is_file(), name
    report = (tmp_path / "dagger" / "tiny-run" / "dagger.md").read_text().splitlines()
    assert report[2].startswith("| 0 | behaviour cloning") and report[3].startswith("| 1 | iteration 0's policy (0.5000)")
    assert (tmp_path / "dagger" / "tiny-run" / "dagger.png").is_file()

    # Run again: everything is kept.
    again = subprocess.run(command, env=environment, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-4000:]
    assert again.stdout.count("kept:") == 5, again.stdout


def test_a_tiny_dagger_iteration_on_ray_records_and_chooses_as_without_it(tmp_path, rng):
    """`scripts/dagger --ray local`: the round recorded as Ray shares and the closed loops
    played on Ray give the files a run without Ray gives."""
    write_dataset(tmp_path / "data-template" / "train", [1, 2, 3], 16, rng)
    write_dataset(tmp_path / "data-template" / "test", [10000], 16, rng)
    files = {}
    for mode, extra in (("serial", []), ("ray", ["--ray", "local"])):
        root = tmp_path / mode
        data = root / "data"
        for part in ("train", "test"):
            (data / part).mkdir(parents=True)
            for source in (tmp_path / "data-template" / part).iterdir():
                (data / part / source.name).write_bytes(source.read_bytes())
        base = root / "models" / "base"
        argv = ["--kind", "cnn", "--dataset", str(data / "train"), "--out", str(base), "--epochs", "1"]
        argv += ["--validation-episodes", "1", "--batch-size", "16", "--threads", "1"]
        argv += ["--checkpoint-dir", str(root / "checkpoints" / "base")]
        assert train_main(argv) == 0
        environment = dict(
            os.environ,
            DRIBBLE_DATA=str(data),
            DRIBBLE_DAGGER_DIR=str(root / "dagger"),
            DRIBBLE_CHECKPOINTS=str(root / "checkpoints"),
            DRIBBLE_DOMAIN=f"dribble-dagger-{mode}-{os.getpid()}",
        )
        command = [str(REPOSITORY / "scripts" / "dagger"), "--base", str(base), "--iterations", "1"]
        command += ["--episodes", "2", "--tiny", "--skip-eval", *extra]
        result = subprocess.run(command, env=environment, capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
        if extra:
            assert "ray: " in result.stdout, result.stdout[-2000:]
        round_dir = data / "dagger" / "base-warm" / "round-1"
        index = json.loads((round_dir / "dataset.json").read_text())
        # The policy's path differs between the two trees, and so does its content hash (each
        # tree trained its base, and the manifest records the training's wall time); the
        # network itself and everything else must not.
        index["driver"]["policy"] = Path(index["driver"]["policy"]).name
        assert len(index["driver"].pop("policy_hash")) == 64
        assert index["driver"]["engine"] == "compiled"
        files[mode] = (index, {p.name: p.read_bytes() for p in round_dir.glob("*.npz")})
        # A closed loop through scripts/closed-loop with DRIBBLE_RAY as scripts/dagger sets it.
        summary = root / "select.json"
        loop = subprocess.run(
            [str(REPOSITORY / "scripts" / "closed-loop"), str(base / "policy.toml"), "20000..20002", str(summary),
             str(root / "select.png"), f"select-{mode}", "--time-limit", "2"],
            env={**environment, **({"DRIBBLE_RAY": "local"} if extra else {})},
            capture_output=True, text=True, timeout=600,
        )  # fmt: skip
        assert loop.returncode == 0, loop.stdout[-3000:] + loop.stderr[-3000:]
        files[mode + "-loop"] = (data / "eval" / f"select-{mode}.json").read_bytes()
    assert files["serial"][0] == files["ray"][0]
    assert files["serial"][1] == files["ray"][1] and len(files["serial"][1]) == 2
    assert files["serial-loop"] == files["ray-loop"]


def test_a_base_that_learned_from_more_data_needs_it_named_and_refuses_any_other(tmp_path, rng):
    """The memory R-CNN learned from the CNN's DAgger rounds too: its own run keeps them, named
    with --base-data and checked against the manifest's hashes before anything is recorded."""
    kept = write_dataset(tmp_path / "round-1", [1000, 1001], 4, rng)
    other = write_dataset(tmp_path / "round-2", [2000], 4, rng)
    kept_hash = json.loads((kept / "dataset.json").read_text())["content_hash"]
    base = tmp_path / "base"
    base.mkdir()
    (base / "policy.toml").write_text(
        'kind = "rcnn"\n[training]\nteacher = "paper"\n'
        'notes = "Adam lr 0.001; 8 lanes of 600-step windows; epoch fraction 1.0; filters 8,16,4,8 (top 8 then 16, '
        'bottom 4 then 8; the paper\'s 16,32,8,16)"\n'
        f'added_datasets = [{{ name = "round-1", hash = "{kept_hash}" }}]\n'
    )
    environment = dict(os.environ, DRIBBLE_BIN_DIR=str(tmp_path / "no-binaries"), DRIBBLE_DAGGER_DIR=str(tmp_path / "dagger"),
                       DRIBBLE_DATA=str(tmp_path / "data"))  # fmt: skip
    command = [str(REPOSITORY / "scripts" / "dagger"), "--base", str(base), "--tiny", "--iterations", "1", "--episodes", "2"]
    for extra, message in (
        ([], "also learned from round-1: name each with --base-data"),
        (["--base-data", str(kept), "--base-data", str(other)], f"--base-data {other}: not among what"),
        (["--base-data", str(kept), "--seed-offset", "998"], "--seed-offset K needs K + episodes at most 999"),
    ):
        result = subprocess.run(command + extra, env=environment, capture_output=True, text=True, timeout=60)
        assert result.returncode != 0 and message in result.stderr, (extra, result.stderr[-2000:])
        assert not (tmp_path / "data" / "dagger").exists(), extra
    # Named as it should be, the run gets past the checks and stops only at the missing binaries,
    # recording the first round on the offset seeds with the base's R-CNN recipe.
    result = subprocess.run(command + ["--base-data", str(kept), "--seed-offset", "500"], env=environment,
                            capture_output=True, text=True, timeout=60)  # fmt: skip
    assert result.returncode != 0 and "seeds 1500..1501" in result.stdout, result.stdout[-2000:] + result.stderr[-2000:]
    assert "its recipe: --epoch-fraction 1.0 --lanes 8 --window 600 --filters 8,16,4,8" in result.stdout, result.stdout[-2000:]
    assert "no-binaries/dribble" in result.stderr, result.stderr[-2000:]


def test_a_shipped_iteration_never_overwrites_a_model_no_dagger_run_shipped(tmp_path):
    from dribble_models.dagger_report import ship_target

    pattern = str(tmp_path / "cnn-dagger{iteration}-observable")
    assert ship_target(pattern, 3) == tmp_path / "cnn-dagger3-observable"
    other = tmp_path / "cnn-dagger2-observable"
    other.mkdir()
    (other / "policy.toml").write_text("")
    with pytest.raises(ValueError, match="no DAgger run shipped"):
        ship_target(pattern, 2)
    (other / "ITERATION").write_text("2\n")
    assert ship_target(pattern, 2) == other
