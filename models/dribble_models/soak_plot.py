"""Plots a soak's CSV (`dribble soak`): the controller's memory and open files, and the
latency of its commands per second against the 2 ms tick budget, with lost commands and
missed deadlines marked.

    python -m dribble_models.soak_plot SOAK_DIR [--out SOAK_DIR/soak.png]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

BUDGET_US = 2000.0


def load(directory: Path) -> tuple[dict[str, np.ndarray], dict | None]:
    csv = directory / "soak.csv"
    if not csv.is_file():
        raise SystemExit(f"no {csv}: run `dribble soak` first")
    table = np.genfromtxt(csv, delimiter=",", names=True)
    table = np.atleast_1d(table)
    columns = {name: np.asarray(table[name], dtype=float) for name in table.dtype.names}
    summary_path = directory / "soak.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else None
    return columns, summary


def plot(columns: dict[str, np.ndarray], summary: dict | None, out: Path) -> None:
    minutes = columns["elapsed_s"] / 60.0
    figure, (memory, latency) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    title = "dribble soak: controller process at 30 Hz cameras, 100 Hz ticks"
    if summary:
        title += f" ({summary['minutes']:g} min, {summary['commands']:,} commands, {summary['lost']} lost)"
    figure.suptitle(title, fontsize=11)

    memory.plot(minutes, columns["rss_kib"] / 1024.0, color="tab:blue", label="resident memory (RSS)")
    memory.set_ylabel("RSS (MiB)", color="tab:blue")
    low, high = np.min(columns["rss_kib"]) / 1024.0, np.max(columns["rss_kib"]) / 1024.0
    memory.set_ylim(max(0.0, low - 2.0), high + 2.0)
    files = memory.twinx()
    files.plot(minutes, columns["open_files"], color="tab:gray", linestyle="--", label="open files")
    files.set_ylabel("open files", color="tab:gray")
    files.set_ylim(0, max(10, np.max(columns["open_files"]) * 1.5))
    lines = memory.get_lines() + files.get_lines()
    memory.legend(lines, [line.get_label() for line in lines], loc="lower right", fontsize=8)
    memory.grid(alpha=0.3)

    latency.plot(minutes, columns["latency_p50_us"], label="p50 per second", color="tab:green")
    latency.plot(minutes, columns["latency_p99_us"], label="p99 per second", color="tab:orange")
    latency.plot(minutes, columns["latency_max_us"], label="max per second", color="tab:red", alpha=0.6)
    latency.axhline(BUDGET_US, color="black", linestyle=":", label="2 ms tick budget")
    bad = (columns["missed"] > 0) | (columns["lost"] > 0)
    if np.any(bad):
        latency.scatter(minutes[bad], columns["latency_max_us"][bad], marker="x", color="black",
                        label="a second with a missed deadline or lost command", zorder=5)
    latency.set_yscale("log")
    latency.set_ylabel("tick start to command received (µs)")
    latency.set_xlabel("minutes")
    latency.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), fontsize=8, ncol=3)
    latency.grid(alpha=0.3, which="both")
    figure.tight_layout()
    figure.savefig(out, dpi=100)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("directory", type=Path, help="the soak's output directory (soak.csv, soak.json)")
    parser.add_argument("--out", type=Path, help="the PNG to write (default: DIRECTORY/soak.png)")
    args = parser.parse_args(argv)
    columns, summary = load(args.directory)
    out = args.out or args.directory / "soak.png"
    plot(columns, summary, out)
    print(f"soak plot: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
