"""A dataset written by the Rust recorder loads in NumPy as DESIGN.md says it should."""

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPOSITORY = Path(__file__).resolve().parents[2]


def dribble_binary() -> Path:
    """The `dribble` tool: $DRIBBLE_BIN (set by scripts/test), else the usual build places."""
    candidates = [os.environ.get("DRIBBLE_BIN")]
    target = os.environ.get("CARGO_TARGET_DIR")
    if target:
        candidates.append(str(Path(target) / "release" / "dribble"))
    candidates += [
        str(Path.home() / ".cache" / "dribble" / "target" / "release" / "dribble"),
        str(REPOSITORY / "target" / "release" / "dribble"),
    ]
    for candidate in candidates:
        if candidate and Path(candidate).is_file():
            return Path(candidate)
    pytest.fail("the dribble binary is not built: run `cargo build --release` (scripts/test does)")


def test_a_recorded_episode_round_trips_into_numpy(tmp_path):
    out = tmp_path / "dataset"
    result = subprocess.run(
        [str(dribble_binary()), "record", "--episodes", "10003..10004", "--time-limit", "3", "--out", str(out)],
        capture_output=True,
        text=True,
        env={**os.environ, "XDG_RUNTIME_DIR": str(tmp_path)},
    )
    assert result.returncode == 0, result.stdout + result.stderr
    index = json.loads((out / "dataset.json").read_text())
    (entry,) = index["episodes"]
    assert entry["seed"] == 10003 and entry["outcome"] == "time_limit"
    with np.load(out / entry["file"]) as episode:
        rows = entry["rows"]
        expected = {
            "top": (np.uint8, (rows, 120, 160)),
            "bottom": (np.uint8, (rows, 60, 80)),
            "command": (np.float32, (rows, 3)),
            "robot_pose": (np.float32, (rows, 3)),
            "ball": (np.float32, (rows, 2)),
            "time_s": (np.float64, (rows,)),
            "phase": (np.uint8, (rows,)),
        }
        assert sorted(episode.files) == sorted(expected)
        for name, (dtype, shape) in expected.items():
            assert episode[name].dtype == dtype, name
            assert episode[name].shape == shape, name
        assert rows == 90, "30 camera pairs a second for 3 s"
        assert np.all(np.abs(episode["command"]) <= 1.0)
        assert np.all(np.diff(episode["time_s"]) > 0)
        assert set(np.unique(episode["phase"])) <= {0, 1, 2, 3}
        # The thumbnails are images, not blanks: the field and the walls differ in brightness.
        assert episode["top"].std() > 10
    shutil.rmtree(out)
