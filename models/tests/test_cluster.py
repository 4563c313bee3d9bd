"""Recording and evaluation sharded over Ray: on a local cluster of two nodes (two raylets on
this machine standing in for two machines), the merged dataset is a serial `dribble record`'s
byte for byte and the merged evaluation a serial `dribble eval`'s; a stopped recording
resumes with the missing seeds only; shares that disagree are not merged."""

import filecmp
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dribble_models import cluster
from test_dataset import REPOSITORY, dribble_binary

TIME_LIMIT = ["--time-limit", "1.5"]


@pytest.fixture(scope="module")
def ray_cluster():
    """Two one-CPU nodes (two shares at once must run on different nodes), held by a child
    process (`ray_nodes.py` says why): the head's address."""
    pytest.importorskip("ray")
    nodes = subprocess.Popen([sys.executable, str(Path(__file__).with_name("ray_nodes.py"))],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        address = nodes.stdout.readline().strip()
        assert address, "the Ray nodes did not start"
        yield address
    finally:
        nodes.stdin.close()
        nodes.wait(timeout=120)


def run_cluster(*arguments, cwd=None) -> str:
    """`python -m dribble_models.cluster ARGUMENTS` as a child process: its standard output."""
    return succeeds([sys.executable, "-m", "dribble_models.cluster", *arguments], cwd=cwd,
                    env={**os.environ, "PYTHONPATH": str(REPOSITORY / "models")})  # fmt: skip


@pytest.fixture(autouse=True)
def binaries(monkeypatch, tmp_path):
    monkeypatch.setenv("DRIBBLE_BIN_DIR", str(dribble_binary().parent))
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))


def succeeds(command, cwd=None, env=None) -> str:
    """Runs `command`, which must succeed: its standard output."""
    run = subprocess.run(command, capture_output=True, text=True, cwd=cwd, env=env)
    assert run.returncode == 0, run.stdout + run.stderr
    return run.stdout


def dribble(*arguments, cwd=None) -> str:
    return succeeds([str(dribble_binary()), *arguments], cwd=cwd)


def same_directories(a: Path, b: Path) -> bool:
    comparison = filecmp.dircmp(a, b)
    names = sorted(comparison.left_list)
    if names != sorted(comparison.right_list):
        return False
    _, mismatch, errors = filecmp.cmpfiles(a, b, names, shallow=False)
    return not mismatch and not errors


def test_a_recording_on_two_nodes_is_the_serial_recording_byte_for_byte_and_resumes(ray_cluster, tmp_path):
    serial = tmp_path / "serial"
    dribble("record", "--episodes", "10003..10006", "--out", str(serial), *TIME_LIMIT)
    sharded = tmp_path / "sharded"
    # First a part (a run stopped after its first shares), then all: only 10005 is new.
    arguments = ["--address", ray_cluster, "--out", str(sharded), "--share", "1"]
    first = run_cluster("record", "--episodes", "10003..10005", *arguments, "--", *TIME_LIMIT)
    nodes = {
        line.split(" episodes on ")[1].split(",")[0]
        for line in first.splitlines()
        if line.startswith("share ")
    }
    assert len(nodes) == 2, first  # one share on each node
    second = run_cluster("record", "--episodes", "10003..10006", *arguments, "--", *TIME_LIMIT)
    assert "2 episode(s) already in" in second and "1 share(s)" in second, second
    assert same_directories(serial, sharded)
    hash_line = [line for line in second.splitlines() if "content hash" in line][0]
    assert (serial / "dataset.json").read_text().count(hash_line.rsplit(" ", 1)[1]) == 1


def test_an_evaluation_on_two_nodes_with_shipped_binaries_is_the_serial_one(ray_cluster, tmp_path):
    policy = "models/policy/cnn-dagger1-observable/policy.toml"  # relative: shipped to each node
    serial = tmp_path / "serial.json"
    dribble("eval", "--driver", policy, "--episodes", "10000..10003", *TIME_LIMIT,
            "--domain", f"cluster-test-{os.getpid()}", "--trajectories", str(serial),
            "--plot", str(tmp_path / "serial.png"), "--controller-log",
            str(tmp_path / "controller.log"), cwd=REPOSITORY)  # fmt: skip
    sharded = tmp_path / "sharded.json"
    run_cluster("eval", "--episodes", "10000..10003", "--address", ray_cluster, "--share", "2",
                "--ship", "--trajectories", str(sharded), "--plot", str(tmp_path / "sharded.png"),
                "--", "--driver", policy, *TIME_LIMIT, cwd=REPOSITORY)  # fmt: skip
    assert sharded.read_bytes() == serial.read_bytes()
    assert (tmp_path / "sharded.png").stat().st_size > 0


def test_shares_of_different_recordings_are_not_merged(tmp_path):
    one, other = tmp_path / "one", tmp_path / "other"
    dribble("record", "--episodes", "10003..10004", "--out", str(one), "--time-limit", "1")
    dribble("record", "--episodes", "10004..10005", "--out", str(other), "--time-limit", "1.2")
    run = subprocess.run(
        [str(dribble_binary()), "merge", "dataset", "--out", str(tmp_path / "merged"), str(one), str(other)],
        capture_output=True,
        text=True,
    )
    assert run.returncode != 0 and "another configuration" in run.stderr, run.stderr
    assert not (tmp_path / "merged" / "dataset.json").exists()
    twice = subprocess.run(
        [str(dribble_binary()), "merge", "dataset", "--out", str(tmp_path / "merged"), str(one), str(one)],
        capture_output=True,
        text=True,
    )
    assert twice.returncode != 0 and "episode 10003 is in" in twice.stderr, twice.stderr


def test_shares_are_runs_of_consecutive_seeds_cut_at_gaps():
    assert cluster.shares([5, 1, 2, 3, 7, 8], 2) == [range(1, 3), range(3, 4), range(5, 6), range(7, 9)]
    assert cluster.seed_range("test") == range(10000, 10020)
    with pytest.raises(SystemExit, match="set per share"):
        cluster.check_passed_arguments(["--out=x"])
    with pytest.raises(SystemExit, match="relative path"):
        cluster.shipped_policy("/abs/policy.toml")
