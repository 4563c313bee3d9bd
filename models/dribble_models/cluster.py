"""Recording and evaluation sharded over a Ray cluster.

    PYTHONPATH=models python -m dribble_models.cluster record --episodes 0..100 --out DATA
    PYTHONPATH=models python -m dribble_models.cluster eval --episodes 30000..30100 \\
        --trajectories fresh.json --plot fresh.png -- --driver models/policy/cnn/policy.toml
    ... --address HOST:6379      # join a running cluster (`ray start --head` on one machine,
                                 # `ray start --address HOST:6379` on the others)

The seeds are cut into shares of consecutive seeds (``--share`` episodes each); each share is a
Ray task that runs the ``dribble`` binary on its node (``record`` or ``eval`` with the share's
``--episodes``, an iceoryx2 domain of its own, the node's lavapipe renderer) and returns what it
wrote. The shares are put together by ``dribble merge`` as one serial run of the same seeds
writes them: the same episode files, ``dataset.json`` and content hash; the same trajectories,
table and goal count. A recording merges each share as it arrives, so a run that is stopped
keeps its finished shares and a second run records only the seeds still missing.

Without ``--address`` Ray starts on this machine and uses its cores. ``--workers N`` caps the
shares played at once (default: the cluster's CPUs); one episode renders on more than one
thread (lavapipe), so on a small machine fewer workers than cores can be faster.

How a node gets the binaries: by default every node runs ``dribble`` from the same path as
here (``$DRIBBLE_BIN_DIR``, else the release build in ``$CARGO_TARGET_DIR``): a shared file
system, or the same checkout built in place on each node. With ``--ship`` the binaries
(``dribble``, ``dribble-controller``) and the driving policy's directory travel with the job
through Ray's object store and are unpacked on each node (binaries cached by content hash), so
a node needs only Python with Ray, Mesa's Vulkan driver and the libraries the binaries link; a
shipped policy must then be named by a relative path, which every node recreates, so that the
recorded ``dataset.json`` names it as a serial run does. Arguments after ``--`` go to
``dribble record``/``eval`` unchanged (``--driver``, ``--label-with``, ``--beta``,
``--teacher``, ``--isa``, ``--time-limit``, ...).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

# Flags each share sets for itself.
PER_SHARE_FLAGS = {"--episodes", "--out", "--trajectories", "--plot", "--domain",
                   "--controller-log", "--jobs"}  # fmt: skip
LAVAPIPE = "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json"


def seed_range(text: str) -> range:
    """`train` (0..99), `test` (10000..10019) or START..END (END excluded)."""
    named = {"train": range(0, 100), "test": range(10000, 10020)}
    if text in named:
        return named[text]
    start, separator, end = text.partition("..")
    if not separator or not start.isdigit() or not end.isdigit() or int(end) <= int(start):
        raise argparse.ArgumentTypeError(f"{text!r} is not train, test or START..END")
    return range(int(start), int(end))


def shares(seeds: list[int], size: int) -> list[range]:
    """Runs of at most `size` consecutive seeds covering `seeds` (sorted), cut at gaps too."""
    runs: list[range] = []
    for seed in sorted(seeds):
        last = runs[-1] if runs else None
        if last is not None and seed == last.stop and len(last) < size:
            runs[-1] = range(last.start, seed + 1)
        else:
            runs.append(range(seed, seed + 1))
    return runs


def binary_dir() -> Path:
    """Where this machine's `dribble` binaries are."""
    if os.environ.get("DRIBBLE_BIN_DIR"):
        return Path(os.environ["DRIBBLE_BIN_DIR"])
    target = os.environ.get("CARGO_TARGET_DIR", str(Path.home() / ".cache/dribble/target"))
    return Path(target) / "release"


def check_passed_arguments(arguments: list[str]) -> None:
    for argument in arguments:
        if argument.split("=")[0] in PER_SHARE_FLAGS:
            raise SystemExit(f"cluster: {argument.split('=')[0]} is set per share; give it before --")


def driver_of(arguments: list[str]) -> str:
    for i, argument in enumerate(arguments):
        if argument == "--driver" and i + 1 < len(arguments):
            return arguments[i + 1]
        if argument.startswith("--driver="):
            return argument.split("=", 1)[1]
    return "teacher"


def shipped_policy(driver: str) -> dict[str, bytes]:
    """The files of the driving policy's directory, by relative path (none for the teacher)."""
    if driver in ("teacher", "expert"):
        return {}
    path = Path(driver)
    if path.is_absolute() or ".." in path.parts:
        raise SystemExit(
            f"cluster: with --ship the policy must be a relative path below here, not {driver}: "
            "each node recreates it there, so that the recording names it as a serial run does"
        )
    return {str(p): p.read_bytes() for p in sorted(path.parent.iterdir()) if p.is_file()}


@dataclass
class ShareResult:
    seeds: range
    returncode: int
    log: str
    files: dict[str, bytes] = field(default_factory=dict)
    wall_s: float = 0.0
    cpu_s: float = 0.0
    node: str = ""


def unpack_binaries(shipped: dict[str, bytes]) -> Path:
    """The shipped binaries in a node-local directory named by their content hash."""
    digest = hashlib.sha256()
    for name in sorted(shipped):
        digest.update(name.encode() + b"\0" + shipped[name])
    directory = Path(tempfile.gettempdir()) / "dribble-ray-binaries" / digest.hexdigest()[:16]
    if not (directory / "dribble").is_file():
        partial = directory.with_name(directory.name + f".{os.getpid()}.partial")
        partial.mkdir(parents=True, exist_ok=True)
        for name, data in shipped.items():
            (partial / name).write_bytes(data)
            (partial / name).chmod(0o755)
        try:
            partial.rename(directory)
        except OSError:  # another task on this node unpacked them first
            shutil.rmtree(partial, ignore_errors=True)
    return directory


def play_share(
    command: str,
    seeds: range,
    arguments: list[str],
    bin_dir: str,
    shipped_binaries: dict[str, bytes] | None,
    shipped_files: dict[str, bytes],
    working_dir: str,
) -> ShareResult:
    """Runs `dribble COMMAND` on `seeds` here (a Ray task's body) and returns what it wrote."""
    started = time.perf_counter()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    scratch = Path(tempfile.mkdtemp(prefix="dribble-share-"))
    try:
        binaries = unpack_binaries(shipped_binaries) if shipped_binaries else Path(bin_dir)
        dribble = binaries / "dribble"
        if not dribble.is_file():
            return ShareResult(seeds, 127, f"{node_name()}: no {dribble} on this node "
                               "(build it there, share the path, or use --ship)")  # fmt: skip
        cwd = Path(working_dir)
        if shipped_files:
            cwd = scratch / "work"
            for name, data in shipped_files.items():
                (cwd / name).parent.mkdir(parents=True, exist_ok=True)
                (cwd / name).write_bytes(data)
        environment = dict(os.environ)
        if not environment.get("DRIBBLE_GPU") and Path(LAVAPIPE).is_file():
            environment["VK_ICD_FILENAMES"] = LAVAPIPE
        environment.setdefault("XDG_RUNTIME_DIR", str(scratch))
        environment.pop("DRIBBLE_DOMAIN", None)
        # Ray's workers run with RUST_BACKTRACE set: anyhow would end a failed command's log
        # with a backtrace long enough to push its error message out of the tail reported.
        environment.setdefault("RUST_LIB_BACKTRACE", "0")
        out = scratch / "out"
        line = [str(dribble), command, *arguments,
                "--episodes", f"{seeds.start}..{seeds.stop}",
                "--domain", f"ray-{uuid.uuid4().hex[:12]}",
                "--controller-log", str(scratch / "controller.log")]  # fmt: skip
        if command == "record":
            line += ["--out", str(out)]
        else:
            out.mkdir()
            line += ["--trajectories", str(out / "trajectories.json"),
                     "--plot", str(scratch / "plot.png")]  # fmt: skip
        run = subprocess.run(line, cwd=cwd, env=environment, capture_output=True, text=True)
        log = run.stdout + run.stderr
        if (scratch / "controller.log").is_file():
            log += "\n-- controller log --\n" + (scratch / "controller.log").read_text()[-4000:]
        files = {}
        if run.returncode == 0:
            files = {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()}
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return ShareResult(seeds, run.returncode, log, files, time.perf_counter() - started,
                           cpu, node_name())  # fmt: skip
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def node_name() -> str:
    """This machine's name and, inside Ray, the node's short id (two nodes may share a machine)."""
    try:
        import ray

        return f"{socket.gethostname()}/{ray.get_runtime_context().get_node_id()[:8]}"
    except Exception:  # not in a Ray worker
        return socket.gethostname()


def recorded_seeds(out: Path) -> set[int]:
    index = out / "dataset.json"
    if not index.is_file():
        return set()
    return {e["seed"] for e in json.loads(index.read_text())["episodes"]}


def run_dribble(binaries: Path, arguments: list[str]) -> str:
    run = subprocess.run([str(binaries / "dribble"), *arguments], capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"cluster: dribble {' '.join(arguments[:2])} failed:\n{run.stdout}{run.stderr}")
    return run.stdout


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dribble_models.cluster",
        description=__doc__.split("\n\n")[0],
        epilog="Arguments after -- go to dribble record/eval unchanged.",
    )
    parser.add_argument("command", choices=["record", "eval"])
    parser.add_argument("--episodes", type=seed_range, required=True,
                        help="train, test or START..END (END excluded)")
    parser.add_argument("--out", type=Path, help="record: the merged dataset directory")
    parser.add_argument("--trajectories", type=Path, help="eval: the merged trajectories file")
    parser.add_argument("--plot", type=Path, help="eval: the trajectory plot")
    parser.add_argument("--address", help="a running Ray cluster (default: start one here)")
    parser.add_argument("--workers", type=int, help="shares played at once (default: the cluster's CPUs)")
    parser.add_argument("--share", type=int, default=5, help="episodes per share (default 5)")
    parser.add_argument("--ship", action="store_true",
                        help="send the binaries and the policy with the job instead of finding them on each node")
    argv = list(sys.argv[1:] if argv is None else argv)
    passed = argv[argv.index("--") + 1 :] if "--" in argv else []
    args = parser.parse_args(argv[: argv.index("--")] if "--" in argv else argv)
    args.passed = passed
    check_passed_arguments(args.passed)
    if args.command == "record" and args.out is None:
        parser.error("record needs --out")
    if args.command == "eval" and args.trajectories is None:
        parser.error("eval needs --trajectories")
    if args.share < 1:
        parser.error("--share is at least 1")

    import ray  # imported here: --help and argument errors need no cluster

    binaries = binary_dir()
    if not (binaries / "dribble").is_file():
        raise SystemExit(f"cluster: no dribble binary in {binaries} (cargo build --release, or DRIBBLE_BIN_DIR)")
    todo = list(args.episodes)
    if args.command == "record":
        done = recorded_seeds(args.out)
        todo = [s for s in todo if s not in done]
        if len(todo) < len(args.episodes):
            print(f"{len(args.episodes) - len(todo)} episode(s) already in {args.out}, kept")
    work = shares(todo, args.share)

    ray.init(address=args.address, include_dashboard=False, log_to_driver=False,
             logging_level="warning")  # fmt: skip
    workers = args.workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
    nodes = len([n for n in ray.nodes() if n["Alive"]])
    print(f"ray: {nodes} node(s), {workers} worker(s), {len(work)} share(s) of up to "
          f"{args.share} episodes, {len(todo)} episodes")  # fmt: skip
    shipped_binaries = shipped_files = None
    if args.ship:
        shipped_binaries = ray.put({name: (binaries / name).read_bytes()
                                    for name in ("dribble", "dribble-controller")
                                    if (binaries / name).is_file()})  # fmt: skip
        shipped_files = ray.put(shipped_policy(driver_of(args.passed)))
    if __name__ != "__main__":
        # The task's code travels with it: a node needs no copy of this package on its path.
        ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    task = ray.remote(num_cpus=1, max_retries=0)(play_share)

    scratch = Path(tempfile.mkdtemp(prefix="dribble-cluster-"))
    started = time.perf_counter()
    pending, waiting, finished, failures, cpu = list(work), [], [], [], 0.0
    try:
        from tqdm import tqdm

        progress = tqdm(total=len(todo), unit="episode", disable=not sys.stderr.isatty())
        while pending or waiting:
            while pending and len(waiting) < workers:
                seeds = pending.pop(0)
                waiting.append(task.remote(args.command, seeds, args.passed, str(binaries),
                                           shipped_binaries, shipped_files or {}, os.getcwd()))  # fmt: skip
            ready, waiting = ray.wait(waiting, num_returns=1)
            result: ShareResult = ray.get(ready[0])
            cpu += result.cpu_s
            progress.update(len(result.seeds))
            span = f"{result.seeds.start}..{result.seeds.stop}"
            if result.returncode != 0:
                failures.append(f"share {span} failed (exit {result.returncode}):\n{result.log[-3000:]}")
                progress.write(f"share {span}: failed on {result.node or 'its node'}")
                continue
            directory = scratch / f"share-{result.seeds.start}"
            for name, data in result.files.items():
                (directory / name).parent.mkdir(parents=True, exist_ok=True)
                (directory / name).write_bytes(data)
            if args.command == "record":
                # Merged at once: a stopped run keeps every finished share.
                run_dribble(binaries, ["merge", "dataset", "--out", str(args.out), str(directory)])
                shutil.rmtree(directory)
            else:
                finished.append(directory / "trajectories.json")
            progress.write(f"share {span}: {len(result.seeds)} episodes on {result.node}, "
                           f"{result.wall_s:.0f} s, {result.cpu_s:.0f} CPU s")  # fmt: skip
        progress.close()
        wall = time.perf_counter() - started
        if args.command == "record":
            if args.out.joinpath("dataset.json").is_file():
                print(summary_of_dataset(args.out))
        elif finished:
            finished.sort(key=lambda p: int(p.parent.name.split("-")[1]))
            merge = ["merge", "trajectories", "--out", str(args.trajectories),
                     "--driver", driver_of(args.passed)]  # fmt: skip
            if args.plot:
                merge += ["--plot", str(args.plot)]
            print(run_dribble(binaries, merge + [str(p) for p in finished]), end="")
        if todo:
            print(f"{len(todo)} episodes in {wall:.0f} s: {3600 * len(todo) / wall:.0f} episodes per "
                  f"hour, {cpu:.0f} CPU s in the shares ({cpu / wall:.2f} cores busy on average)")  # fmt: skip
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
        ray.shutdown()
    if failures:
        print("\n\n".join(failures), file=sys.stderr)
        return 1
    return 0


def summary_of_dataset(out: Path) -> str:
    index = json.loads((out / "dataset.json").read_text())
    episodes = index["episodes"]
    goals = sum(e["outcome"] == "goal" for e in episodes)
    rows = sum(e["rows"] for e in episodes)
    return (f"{out / 'dataset.json'}: {len(episodes)} episodes, {goals} goals, {rows} rows, "
            f"content hash {index.get('content_hash')}")  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
