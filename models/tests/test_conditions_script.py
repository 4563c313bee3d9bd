"""scripts/conditions plays a hundred seeds in pieces of 20 and loses at most one piece to a
run cut off: in a throwaway git repository with the script, a one-file policy and a stand-in
`dribble` (DRIBBLE_BIN_DIR) whose episodes are a function of their seed."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

#: A stand-in for `dribble eval` and `dribble merge trajectories`: every third seed runs out
#: of time, the rest score; each range it plays is logged; it fails on DRIBBLE_FAIL_ON's range.
STAND_IN = """#!{python}
import json, os, sys
a = sys.argv[1:]
if a[0] == "eval":
    seeds = a[a.index("--episodes") + 1]
    if seeds == os.environ.get("DRIBBLE_FAIL_ON"):
        sys.exit("the machine went away")
    start, stop = map(int, seeds.split(".."))
    episodes = [{{"seed": s, "outcome": "time_limit" if s % 3 == 0 else "goal", "duration_s": 10.0,
                 "computed_commands": 300, "failure": None, "robot": [[0.0, 0.0], [1.0, 0.0]],
                 "ball": [[2.0, 0.0], [4.5, 0.0]]}} for s in range(start, stop)]
    out = a[a.index("--trajectories") + 1]
    json.dump({{"engine": "compiled (avx2+fma)", "conditions": a[a.index("--condition") + 1], "episodes": episodes}}, open(out, "w"))
    with open(os.environ["DRIBBLE_PLAYED"], "a") as log:
        log.write(seeds + "\\n")
else:
    print("goals: merged")
"""


def git(repo: Path, *arguments: str) -> None:
    subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", *arguments], check=True, capture_output=True)


@pytest.fixture
def sandbox(tmp_path):
    """A repository with scripts/conditions, the summaries' code and a policy, all committed,
    and the environment that runs the script there with the stand-in and a home of its own."""
    repo = tmp_path / "repo"
    (repo / "scripts").mkdir(parents=True)
    for script in ("conditions", "rendering-env"):
        shutil.copy2(REPO / "scripts" / script, repo / "scripts" / script)
    (repo / "models" / "policy" / "p").mkdir(parents=True)
    (repo / "models" / "policy" / "p" / "policy.toml").write_text("format = 1\n")
    os.symlink(REPO / "models" / "dribble_models", repo / "models" / "dribble_models")
    git(repo, "init", "-q")
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "a policy")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "dribble").write_text(STAND_IN.format(python=sys.executable))
    (bin_dir / "dribble").chmod(0o755)
    env = {
        **os.environ,
        "HOME": str(tmp_path / "home"),
        "DRIBBLE_BIN_DIR": str(bin_dir),
        "DRIBBLE_VENV": str(Path(sys.executable).parent.parent),
        "DRIBBLE_PLAYED": str(tmp_path / "played.log"),
    }
    return repo, env, tmp_path / "played.log"


def conditions(repo: Path, env: dict, **extra: str) -> subprocess.CompletedProcess:
    command = ["scripts/conditions", "--policy", "models/policy/p", "--seeds", "fresh", "--conditions", "noise", "--no-report"]
    return subprocess.run(command, cwd=repo, env={**env, **extra}, capture_output=True, text=True, timeout=120)


def played(log: Path) -> list[str]:
    return log.read_text().split() if log.exists() else []


def test_a_hundred_seeds_are_five_pieces_joined_into_one_summary(sandbox):
    repo, env, log = sandbox
    run = conditions(repo, env)
    assert run.returncode == 0, run.stderr
    assert played(log) == ["30000..30020", "30020..30040", "30040..30060", "30060..30080", "30080..30100"]
    summary = json.loads((repo / "models/conditions/p/fresh/noise-3.json").read_text())
    assert [e["seed"] for e in summary["episodes"]] == list(range(30000, 30100))
    assert sum(e["outcome"] == "goal" for e in summary["episodes"]) == 66
    # The first 20 are the fresh20 set's own summary; the other pieces are gone once joined.
    assert len(json.loads((repo / "models/conditions/p/fresh20/noise-3.json").read_text())["episodes"]) == 20
    assert not (repo / "models/conditions/p/fresh/parts").exists()


def test_a_run_cut_off_loses_one_piece_and_committed_pieces_are_not_played_again(sandbox):
    repo, env, log = sandbox
    run = conditions(repo, env, DRIBBLE_FAIL_ON="30060..30080")
    assert run.returncode != 0
    parts = sorted(p.name for p in (repo / "models/conditions/p/fresh/parts").iterdir())
    assert parts == ["noise-3.30020-30040.json", "noise-3.30040-30060.json"]
    assert not (repo / "models/conditions/p/fresh/noise-3.json").exists()
    # Commit what was kept, then lose the machine (its cache): only the missing pieces play.
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "pieces")
    shutil.rmtree(Path(env["HOME"]))
    log.unlink()
    run = conditions(repo, env)
    assert run.returncode == 0, run.stderr
    assert played(log) == ["30060..30080", "30080..30100"]
    summary = json.loads((repo / "models/conditions/p/fresh/noise-3.json").read_text())
    assert [e["seed"] for e in summary["episodes"]] == list(range(30000, 30100))


def test_a_piece_of_a_policy_changed_since_is_played_again(sandbox):
    repo, env, log = sandbox
    assert conditions(repo, env, DRIBBLE_FAIL_ON="30040..30060").returncode != 0
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "pieces")
    shutil.rmtree(Path(env["HOME"]))
    log.unlink()
    (repo / "models/policy/p/policy.toml").write_text("format = 1\n# retrained\n")
    run = conditions(repo, env)
    assert run.returncode == 0, run.stderr
    assert played(log) == ["30000..30020", "30020..30040", "30040..30060", "30060..30080", "30080..30100"]
