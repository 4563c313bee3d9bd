"""The book's page on cycles from a pipeline model (issue 49), generated from the files
`cross/cycles` and `python3 cross/cycles.py check` leave in models/performance/:

    python -m dribble_models.cycles_report          # print the page
    python -m dribble_models.book --write            # writes it with the other generated pages

The host check gives the method's error on a core whose time can be measured; the robot
figures carry it as a band: a model that counted `1 + e` times the measured cycles on the host
is taken to count `1 + e` times the robot's, for `e` between the check's tenth and ninetieth
percentiles.
"""

from __future__ import annotations

import json
from pathlib import Path

from .results import V5_CLOCK_HZ, V5_PER_CYCLE, V6_CLOCK_HZ, V6_PER_CYCLE
from .shipping_rules import V5_TICK_BUDGET_MS, V6_TICK_BUDGET_MS

REPOSITORY = Path(__file__).resolve().parents[2]
PERFORMANCE = REPOSITORY / "models" / "performance"
#: The computing tick's budgets the robot package's rule holds a policy to (issue 29's targets).
BUDGET_MS = {"v5": V5_TICK_BUDGET_MS, "v6": V6_TICK_BUDGET_MS}
CORE = {"v5": "Atom Z530 (llvm-mca `atom`: Bonnell)", "v6": "Atom E3845 (llvm-mca `silvermont`)"}


def _load(name: str) -> dict | None:
    path = PERFORMANCE / name
    return json.loads(path.read_text()) if path.exists() else None


def _profiles() -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted(PERFORMANCE.glob("v[56]-*.json"))]


def _band(check: dict | None) -> tuple[float, float] | None:
    if not check:
        return None
    return check["error_p10"], check["error_p90"]


def host_check_section(check: dict | None) -> list[str]:
    if not check:
        return ["No host check recorded yet (`python3 cross/cycles.py check --out models/performance/host-check.json`)."]
    layers = [abs(r["error"]) for r in check["rows"] if r["workload"].startswith("layer")]
    whole = [abs(r["error"]) for r in check["rows"] if not r["workload"].startswith("layer")]
    mean = lambda values: sum(values) / len(values) if values else float("nan")  # noqa: E731
    lines = [
        f"On this host ({check['mcpu']} model of {check.get('model', 'llvm-mca')}, clock "
        f"{check['host_ghz']:.2f} GHz by a chain of dependent multiplications), {check['cases']} "
        "workloads: whole forward passes and single layers, each the fastest of 2000 runs. Error is "
        "model / measured - 1.",
        "",
        f"Median error {check['median_error']:+.0%}; tenth to ninetieth percentile "
        f"{check['error_p10']:+.0%} to {check['error_p90']:+.0%}. Mean absolute error over the "
        f"{len(layers)} single layers (the kernels) {mean(layers):.0%}, over the {len(whole)} whole "
        f"forward passes {mean(whole):.0%}.",
        "",
        "| policy | instruction set | workload | instructions | model cycles | measured cycles | error |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in check["rows"]:
        lines.append(
            f"| {row['policy']} | {row['isa']} | {row['workload']} | {row['instructions']:,} | "
            f"{row['model_cycles']:,} | {row['measured_cycles']:,} | {row['error']:+.0%} |"
        )
    return lines


def tick_section(profiles: list[dict], band: tuple[float, float] | None) -> list[str]:
    lines = [
        "| build | policy | instructions | a cycle (model) | pipeline model | with the host's error band | "
        "flat method | budget |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for profile in profiles:
        build = profile["build"]
        tick = profile["tick"]
        clock = V5_CLOCK_HZ if build == "v5" else V6_CLOCK_HZ
        low, high = V5_PER_CYCLE if build == "v5" else V6_PER_CYCLE
        ms = tick["cycles"] / clock * 1e3
        flat = f"{tick['instructions'] / (high * clock) * 1e3:.2f}-{tick['instructions'] / (low * clock) * 1e3:.2f} ms"
        banded = "-"
        if band:
            fast, slow = ms / (1 + band[1]), ms / (1 + band[0])
            banded = f"{fast:.2f}-{slow:.2f} ms"
        lines.append(
            f"| {build} | {profile['policy']} | {tick['instructions']:,} | {tick['instructions_per_cycle']:.2f} | "
            f"{ms:.2f} ms | {banded} | {flat} | {BUDGET_MS[build]} ms |"
        )
    return lines


def layer_section(profile: dict) -> list[str]:
    clock = V5_CLOCK_HZ if profile["build"] == "v5" else V6_CLOCK_HZ
    kind = "int8" if profile["int8"] else "float"
    lines = [
        f"#### {profile['policy']} on the {profile['build'].upper()} ({CORE[profile['build']]}, {profile['isa']}; "
        f"{profile.get('model', 'llvm-mca')})",
        "",
        f"The core's {kind} peak by the same model: {profile['peak_multiply_adds_per_cycle']:.2f} multiply-adds "
        "a cycle (three interleaved chains of the engine's inner step).",
        "",
        "| step | layer | multiply-adds | weight bytes | activation bytes | instructions | cycles | µs | share of peak |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in profile["layers"]:
        share = f"{row['share_of_peak']:.0%}" if row["multiply_adds"] else "-"
        lines.append(
            f"| {row['index']} | {row['name']} | {row['multiply_adds']:,} | {row['weight_bytes']:,} | "
            f"{row['activation_bytes']:,} | {row['instructions']:,} | {row['cycles']:,} | "
            f"{row['cycles'] / clock * 1e6:.1f} | {share} |"
        )
    return lines


def page() -> str:
    check = _load("host-check.json")
    profiles = _profiles()
    lines = [
        "# Cycles from a pipeline model",
        "",
        "<!-- generated by python -m dribble_models.book --write from models/performance/*.json "
        "(cross/cycles, cross/cycles.py check) -->",
        "",
        "How many cycles a computing tick takes on the Nao's Atom, estimated without an Atom: callgrind "
        "counts every instruction the tick executes, the instructions are cut into blocks, and LLVM's "
        "scheduling model of the core (`llvm-mca`) gives each block's cycles in steady state; the sum of "
        "count times cycles is the estimate (`cross/cycles`, `cross/cycles.py`). It leaves out cache "
        "misses, mispredicted branches and the operating system, so it is checked first on this host, "
        "where time can be measured, and the robot figures carry that error as a band. The flat method "
        "beside it divides the instruction count by a fixed range of instructions a cycle.",
        "",
        "## The tick on the robots",
        "",
        *tick_section(profiles, _band(check)),
        "",
        "## The method on this host",
        "",
        *host_check_section(check),
        "",
        "## Where the time goes",
        "",
    ]
    for profile in profiles:
        lines += [*layer_section(profile), ""]
    lines.append("<!-- end of cycles -->")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(page(), end="")
