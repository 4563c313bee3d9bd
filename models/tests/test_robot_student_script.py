"""scripts/robot-student refuses a DAgger round it could never train on before it records
anything: the unseen venue (evaluation only) and a driver that is not there; and a host
candidate (--host-width) whose camera branches it was told to keep; and a share of the
rows out of [0, 1] for the trainer."""

import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DRIVER = "cnn-conditions-previous-whole-4-16-4-8-int8"


def robot_student(*arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(REPO / "scripts" / "robot-student"), *arguments],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )


@pytest.mark.parametrize("condition", ["unseen-venue:3", "unseen-venue:1,light:3"])
def test_a_round_under_the_unseen_venue_is_refused_before_recording(condition):
    assert (REPO / "models" / "policy" / DRIVER / "policy.toml").is_file()
    run = robot_student("--dagger-round", f"{DRIVER}@{condition}")
    assert run.returncode == 2
    assert "unseen venue is for evaluation only" in run.stderr
    assert "record seeds" not in run.stdout


def test_a_round_whose_driver_is_missing_is_refused_before_recording():
    run = robot_student("--dagger-round", "cnn-conditions-policy-that-is-not-there@venue:4")
    assert run.returncode == 2
    assert "no models/policy/cnn-conditions-policy-that-is-not-there/policy.toml" in run.stderr
    assert "record seeds" not in run.stdout


def test_a_host_candidate_that_keeps_a_students_branches_is_refused_before_recording():
    run = robot_student("--host-width", "--branches-from", "cnn-conditions-previous-rounds-detour5-search-dropout20")
    assert run.returncode == 2
    assert "--host-width trains the whole network (--whole)" in run.stderr
    assert "record seeds" not in run.stdout


@pytest.mark.parametrize("option", ["--previous-shrink", "--mirror"])
@pytest.mark.parametrize("share", ["1.5", "-0.2", "some"])
def test_a_share_of_the_rows_outside_zero_to_one_is_refused_before_recording(option, share):
    run = robot_student(option, share)
    assert run.returncode == 2
    assert f"{option} is a share of the rows, in [0, 1]" in run.stderr
    assert "record seeds" not in run.stdout
