#!/usr/bin/env python3
"""Cycles of a workload from a pipeline model: callgrind's count of every instruction the
workload executes, grouped into blocks, each block's cycles from `llvm-mca` with a core's
scheduling model (issue 49).

    cross/cycles.py estimate --binary B --mcpu atom -- forward --policy P --isa ssse3
    cross/cycles.py check [--out FILE]      # the method against measured time on this host

`estimate` runs the workload under callgrind with `--steps 1` and `--steps 11` (the
`dribble-controller forward` options; the difference is ten steps, start-up and loading
taken out; a hundred for a single layer, whose steps are too short for ten to outweigh the
difference between two loads), disassembles every object the hot instructions live in (`objdump`), cuts them
into blocks (a run of consecutive instructions with the same count, ended by a jump, call
or return), and asks `llvm-mca` for each block's cycles an iteration in steady state
(`-iterations=100`, one file with a region a block). The estimate is the sum of count x
cycles over the blocks. What it leaves out: cache misses, mispredicted branches, the
front end's stalls on code that is not in a loop, and what the operating system does; an
instruction `llvm-mca` cannot read counts at the mean cycles of the rest (the share is
reported). `check` measures how far that is from time on this host (`--mcpu` of this CPU),
over whole forward passes and single layers (`forward --layer K`), so that the robot
figures can carry the error as a band.

Standard library only: it runs on a bare machine beside `valgrind`, `objdump` and
`llvm-mca` (Debian: valgrind, binutils, llvm-22).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import tomllib
from collections import defaultdict
from pathlib import Path

CONTROL = re.compile(r"^(j[a-z]+|call[lq]?|ret[lq]?|loop[a-z]*|jmp[lq]?|ud2|hlt|syscall|int3?)\b")
REPO = Path(__file__).resolve().parent.parent


def llvm_mca() -> str:
    # The newest first: LLVM 16 on models Golden Cove (this host's Sapphire Rapids) itself,
    # where 14 took the older Ice Lake server model.
    for name in ("llvm-mca-22", "llvm-mca-19", "llvm-mca-16", "llvm-mca", "llvm-mca-15", "llvm-mca-14"):
        if shutil.which(name):
            return name
    sys.exit("cross/cycles.py: needs llvm-mca (Debian: apt-get install llvm-22)")


def llvm_mca_version() -> str:
    out = subprocess.run([llvm_mca(), "--version"], capture_output=True, text=True).stdout
    match = re.search(r"LLVM version (\S+)", out)
    return f"llvm-mca {match.group(1)}" if match else llvm_mca()


def callgrind_counts(command: list[str], env: dict | None = None) -> dict[tuple[str, int], int]:
    """Self instruction counts of `command` by (object path, address in the object)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "callgrind.out"
        run = subprocess.run(
            ["valgrind", "--tool=callgrind", "--dump-instr=yes", "--dump-line=no",
             "--compress-strings=no", "--compress-pos=no", f"--callgrind-out-file={out}", *command],
            capture_output=True, text=True, env=env,
        )
        if run.returncode != 0 or not out.exists():
            sys.exit(f"cross/cycles.py: the workload failed under callgrind:\n{run.stderr[-2000:]}")
        counts: dict[tuple[str, int], int] = defaultdict(int)
        obj = "???"
        skip_next = False
        with open(out) as lines:
            for line in lines:
                if line.startswith("ob="):
                    obj = line[3:].strip()
                elif line.startswith("calls="):
                    skip_next = True  # the next cost line is the call's inclusive cost
                elif line.startswith("0x"):
                    if skip_next:
                        skip_next = False
                        continue
                    address, cost = line.split()[:2]
                    counts[(obj, int(address, 16))] += int(cost)
        return counts


@functools.lru_cache(maxsize=None)
def disassemble(path: str, bits: int) -> tuple[dict[int, tuple[str, str]], list[int]]:
    """Each instruction of `path`'s code: address -> (text in AT&T syntax, function), and the
    addresses in order."""
    run = subprocess.run(["objdump", "-d", "--no-show-raw-insn", "-w", path],
                         capture_output=True, text=True)
    if run.returncode != 0:
        return {}, []
    instructions: dict[int, tuple[str, str]] = {}
    order: list[int] = []
    function = "?"
    header = re.compile(r"^[0-9a-f]+ <(.+)>:$")
    body = re.compile(r"^\s*([0-9a-f]+):\s+(.*)$")
    for line in run.stdout.splitlines():
        if match := header.match(line):
            function = match.group(1)
        elif match := body.match(line):
            text = match.group(2).split("#")[0].strip()
            text = re.sub(r"\s*<[^>]*>", "", text)
            if not text or text.startswith("(bad)") or text.startswith("."):
                continue
            address = int(match.group(1), 16)
            instructions[address] = (text, function)
            order.append(address)
    return instructions, order


def blocks_of(counts: dict[int, float], instructions, order) -> list[dict]:
    """Runs of consecutive executed instructions with the same count, each ended by a control
    transfer."""
    blocks: list[dict] = []
    current: dict | None = None
    previous = None
    for address in order:
        count = counts.get(address, 0)
        if count <= 0:
            current = None
            previous = address
            continue
        text, function = instructions[address]
        if text.startswith(("rep", "repz", "repnz", "repe", "repne")):
            # A string instruction: callgrind counts each of its iterations; costed apart.
            blocks.append({"count": count, "function": function, "instructions": [text],
                           "first": address, "last": address, "string": True})
            current = None
            previous = address
            continue
        if current is None or current["count"] != count or current["last"] != previous:
            current = {"count": count, "function": function, "instructions": [], "first": address}
            blocks.append(current)
        current["instructions"].append(text)
        current["last"] = address
        previous = address
        if CONTROL.match(text):
            current = None
    return blocks


#: Cycles of a call or a return: llvm-mca does not model them (it assumes a call takes 100
#: cycles and ignores where a return goes), so they leave its blocks and count apart.
CALL_CYCLES = 2.0


def for_the_model(text: str, mcpu: str) -> str | None:
    """`text` as llvm-mca should see it, None for a call or return (costed apart), or "" for
    what the core cannot run (left out, counted at the mean rate). `tzcnt` on the Atoms,
    which lack BMI, runs as the `bsf` it is encoded over."""
    if re.match(r"^(call|ret)", text):
        return None
    if mcpu in ("atom", "bonnell", "silvermont", "slm"):
        if re.search(r"%[yz]mm|%k[0-7]|^v[a-z]|^(bzhi|shlx|shrx|sarx|rorx|pdep|pext|andn|blsi|blsr|blsmsk|mulx|lzcnt)", text):
            # AVX and BMI code the Atoms cannot run (a C library routine chosen by the host's CPU
            # under valgrind): not modelled, counted at the mean rate.
            return ""
        text = re.sub(r"^tzcnt", "bsf", text)
    return text


def mca_cycles(blocks: list[dict], triple: str, mcpu: str) -> None:
    """Sets each block's `cycles` (an iteration, steady state) from llvm-mca, dropping what
    it cannot read (`unread` counts those instructions)."""
    tool = llvm_mca()
    for block in blocks:
        block["unread"] = 0
        block["calls"] = 0
        if block.get("string"):
            block["cycles"] = string_iteration_cycles(block["instructions"][0], mcpu)
            continue
        modelled = [for_the_model(text, mcpu) for text in block["instructions"]]
        block["calls"] = sum(text is None for text in modelled)
        block["unread"] = sum(text == "" for text in modelled)
        block["instructions"] = [text for text in modelled if text]
        if not block["instructions"]:
            block["cycles"] = 0.0
    pending = [b for b in blocks if not b.get("string") and b["instructions"]]
    while pending:
        with tempfile.NamedTemporaryFile("w", suffix=".s", delete=False) as source:
            line_number = 0
            for i, block in enumerate(pending):
                source.write(f"# LLVM-MCA-BEGIN b{i}\n")
                line_number += 1
                for text in block["instructions"]:
                    source.write(text + "\n")
                    line_number += 1
                    block.setdefault("lines", []).append(line_number)
                source.write("# LLVM-MCA-END\n")
                line_number += 1
            path = source.name
        run = subprocess.run(
            [tool, f"-mtriple={triple}", f"-mcpu={mcpu}", "-iterations=100", "-all-views=false",
             "-summary-view", path],
            capture_output=True, text=True,
        )
        errors = [int(m.group(1)) for m in re.finditer(rf"{re.escape(path)}:(\d+):\d+: error", run.stderr)]
        os.unlink(path)
        unsupported = re.search(r"unsupported instruction.*\n.*instruction:\s*(.+)", run.stderr)
        if unsupported and not errors:
            # An instruction the core's model has no entry for: every copy of it is dropped.
            same = lambda t: re.sub(r",\s*", ",", " ".join(t.split()))  # noqa: E731 (objdump writes "a,b")
            text = same(unsupported.group(1))
            for block in pending:
                lines = block.pop("lines", [])
                errors += [line for t, line in zip(block["instructions"], lines) if same(t) == text]
                block["lines"] = lines
            if not errors:
                # Written differently by objdump (hex offsets, scales): every instruction
                # with its mnemonic goes.
                mnemonic = text.split()[0]
                for block in pending:
                    errors += [line for t, line in zip(block["instructions"], block["lines"])
                               if t.split()[0] in (mnemonic, mnemonic[:-1])]
            if not errors:
                sys.exit(f"cross/cycles.py: llvm-mca cannot model {text!r} and it is not in the blocks")
        if errors:
            # Drop the unreadable instructions and ask again.
            bad = set(errors)
            for block in pending:
                kept = [(text, line) for text, line in zip(block["instructions"], block["lines"]) if line not in bad]
                block["unread"] += len(block["instructions"]) - len(kept)
                block["instructions"] = [text for text, _ in kept]
                block.pop("lines", None)
            pending = [b for b in pending if b["instructions"]]
            for block in blocks:
                if not block["instructions"]:
                    block["cycles"] = 0.0
            continue
        if run.returncode != 0:
            sys.exit(f"cross/cycles.py: llvm-mca failed:\n{run.stderr[-2000:]}")
        totals = [int(m.group(1)) for m in re.finditer(r"Total Cycles:\s+(\d+)", run.stdout)]
        if len(totals) != len(pending):
            sys.exit(f"cross/cycles.py: llvm-mca gave {len(totals)} regions for {len(pending)} blocks")
        for block, total in zip(pending, totals):
            block["cycles"] = total / 100.0
            block.pop("lines", None)
        pending = []


def string_iteration_cycles(text: str, mcpu: str) -> float:
    """Cycles of one iteration of a `rep` string instruction (callgrind counts iterations;
    llvm-mca's fixed cost for the whole instruction says nothing of its length). Cores with
    fast strings (ERMSB: Ivy Bridge on, the host) move about 32 bytes a cycle; the Atoms
    of the Nao V5 (Bonnell) and V6 (Silvermont) are taken at one element a cycle."""
    width = 1
    if re.search(r"(movs|stos|lods|scas|cmps)q\b|%rax", text):
        width = 8
    elif re.search(r"(movs|stos|lods|scas|cmps)l\b|%eax", text):
        width = 4
    elif re.search(r"(movs|stos|lods|scas|cmps)w\b|%ax\b", text):
        width = 2
    if mcpu in ("atom", "bonnell", "silvermont", "slm", "goldmont"):
        return 1.0
    return width / 32.0


#: Steps between the two counted runs of a single layer. Loading a model does not take the
#: same instructions twice (tract's hash maps are seeded at random: two loads of the robot
#: package's model differ by about 80,000 instructions), and over ten steps that difference
#: passed for a tenth of it in each step: a 23,000-instruction layer counted as 50,000. Over
#: a hundred steps it is a hundredth. The whole tick is counted over as many: over ten, the
#: same package's V6 tick counted 929,256 and 917,060 cycles, and another weight set of the
#: same network 969,221 and 916,128, a swing larger than the margin its budget was judged by.
LAYER_STEPS = 100


def estimate(binary: str, workload: list[str], triple: str, mcpu: str, runner: list[str] | None = None,
             steps: int = 10) -> dict:
    """Instructions and cycles of one step of `workload`: its `--steps 1 + steps` minus its
    `--steps 1`, over `steps` (ten for whole passes and ticks, whose steps dwarf the loads'
    differences; [`LAYER_STEPS`] for a single layer)."""
    base = [*(runner or []), binary, *workload]
    one = callgrind_counts([*base, "--steps", "1"])
    more = callgrind_counts([*base, "--steps", str(1 + steps)])
    per_step: dict[tuple[str, int], float] = {}
    for key in set(one) | set(more):
        difference = (more.get(key, 0) - one.get(key, 0)) / steps
        if difference > 0:
            per_step[key] = difference
    bits = 32 if triple.startswith("i686") else 64
    blocks: list[dict] = []
    unmapped = 0.0
    by_object: dict[str, dict[int, float]] = defaultdict(dict)
    for (obj, address), count in per_step.items():
        by_object[obj][address] = count
    for obj, counts in by_object.items():
        instructions, order = disassemble(obj, bits) if os.path.exists(obj) else ({}, [])
        known = {a: c for a, c in counts.items() if a in instructions}
        unmapped += sum(c for a, c in counts.items() if a not in instructions)
        for block in blocks_of(known, instructions, order):
            block["object"] = os.path.basename(obj)
            blocks.append(block)
    mca_cycles(blocks, triple, mcpu)
    instructions = sum(b["count"] * (len(b["instructions"]) + b["unread"] + b.get("calls", 0)) for b in blocks) + unmapped
    modelled = sum(b["count"] * (len(b["instructions"]) + b.get("calls", 0)) for b in blocks)
    cycles = sum(b["count"] * (b["cycles"] + CALL_CYCLES * b.get("calls", 0)) for b in blocks)
    # What the model could not read runs at the mean rate of what it could.
    cycles_all = cycles * instructions / modelled if modelled else 0.0
    hottest = sorted(blocks, key=lambda b: -b["count"] * b["cycles"])[:10]
    return {
        "mcpu": mcpu,
        "instructions": round(instructions),
        "cycles": round(cycles_all),
        "instructions_per_cycle": instructions / cycles_all if cycles_all else None,
        "unmodelled_share": 1 - modelled / instructions if instructions else 0.0,
        "blocks": len(blocks),
        "hottest_blocks": [
            {"function": b["function"][:80], "object": b["object"], "count": b["count"],
             "instructions": len(b["instructions"]), "cycles_each": b["cycles"],
             "share": b["count"] * b["cycles"] / cycles if cycles else 0.0}
            for b in hottest
        ],
    }


def host_ghz() -> float:
    """This core's clock while busy: a chain of dependent 64-bit multiplications, three
    cycles each on every Intel core since Nehalem (a chain of additions of a constant is
    not a clock: Golden Cove's renamer folds them, about 20 "GHz" here), timed: the fastest of
    500 runs of about 2 ms each, so that on a shared machine some run within one time slice
    (five runs of 200 ms read 2.2 GHz for 3.0 with two evaluation jobs beside)."""
    source = r"""
#include <stdio.h>
#include <time.h>
int main(void) {
    unsigned long n = 6000000UL, x = 3, y = 5;
    struct timespec a, b;
    double best = 1e9;
    for (int r = 0; r < 500; r++) {
        clock_gettime(CLOCK_MONOTONIC, &a);
        for (unsigned long i = 0; i < n; i += 30)
            __asm__ volatile("imul %1,%0\n imul %1,%0\n imul %1,%0\n imul %1,%0\n imul %1,%0\n"
                             "imul %1,%0\n imul %1,%0\n imul %1,%0\n imul %1,%0\n imul %1,%0"
                             : "+r"(x) : "r"(y));
        clock_gettime(CLOCK_MONOTONIC, &b);
        double s = (b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec);
        if (s < best) best = s;
    }
    printf("%f\n", n / best / 1e9);
    return (int)(x & 0);
}
"""
    with tempfile.TemporaryDirectory() as tmp:
        c, exe = Path(tmp) / "clock.c", Path(tmp) / "clock"
        c.write_text(source)
        subprocess.run(["gcc", "-O1", "-o", str(exe), str(c)], check=True)
        return float(subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout)


def host_mcpu() -> str:
    """LLVM's name for this host's core: AMD's Zen generations by family and model (the
    machines here have been both Intel's and AMD's, and an Intel model of an AMD core
    schedules with the wrong units), Intel's by the newest feature it has."""
    cpuinfo = Path("/proc/cpuinfo").read_text()
    if "AuthenticAMD" in cpuinfo:
        family = int(re.search(r"^cpu family\s*:\s*(\d+)", cpuinfo, re.M).group(1))
        model = int(re.search(r"^model\s*:\s*(\d+)", cpuinfo, re.M).group(1))
        return amd_mcpu(family, model)
    if "amx_tile" in cpuinfo:
        return "sapphirerapids"
    if "avx512f" in cpuinfo:
        return "icelake-server" if "avx512_vbmi2" in cpuinfo else "skylake-avx512"
    return "skylake" if "avx2" in cpuinfo else "x86-64"


def amd_mcpu(family: int, model: int) -> str:
    """Zen 1 to 5 from the CPUID family and model (AMD's processor programming references):
    family 17h is Zen and Zen+ below model 30h, Zen 2 from it; 19h is Zen 3 except the Zen 4
    ranges 10h-1Fh (Genoa), 60h-7Fh and A0h-AFh; 1Ah is Zen 5."""
    if family == 0x17:
        return "znver1" if model < 0x30 else "znver2"
    if family == 0x19:
        zen4 = 0x10 <= model <= 0x1F or 0x60 <= model <= 0x7F or 0xA0 <= model <= 0xAF
        return "znver4" if zen4 else "znver3"
    if family >= 0x1A:
        return "znver5"
    return "x86-64"


def layer_times(binary: str, policy: str, isa: str, runs: int) -> list[dict]:
    run = subprocess.run([binary, "forward", "--policy", policy, "--isa", isa, "--layers", "--steps", str(runs)],
                         capture_output=True, text=True, check=True)
    line = next(l for l in run.stdout.splitlines() if l.startswith("layers "))
    return json.loads(line[len("layers "):])["steps"]


def forward_min_seconds(binary: str, policy: str, isa: str, runs: int) -> float:
    run = subprocess.run([binary, "forward", "--policy", policy, "--isa", isa, "--steps", str(runs), "--no-peak"],
                         capture_output=True, text=True, check=True)
    match = re.search(r"min ([0-9.]+)(ns|µs|us|ms|s)\b", run.stdout)
    if not match:
        sys.exit(f"cross/cycles.py: no time in:\n{run.stdout}")
    scale = {"ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}[match.group(2)]
    return float(match.group(1)) * scale


def check(args) -> None:
    binary = args.binary
    mcpu = args.mcpu or host_mcpu()
    ghz = host_ghz()
    print(f"host clock {ghz:.2f} GHz (dependent multiplications); model {mcpu}", file=sys.stderr)
    robot = (REPO / "models/policy/ROBOT_MODEL").read_text().strip()
    host = (REPO / "models/policy/HOST_MODEL").read_text().strip()
    cases = []
    for policy in ("models/fixtures/cnn", f"models/policy/{host}", f"models/policy/{robot}"):
        for isa in ("ssse3", "avx2+fma"):
            cases.append({"policy": policy, "isa": isa, "layer": None})
    for policy in ("models/fixtures/cnn", f"models/policy/{robot}"):
        for isa in ("ssse3", "avx2+fma"):
            for row in layer_times(binary, f"{policy}/policy.toml", isa, 50):
                if row["min_ns"] >= 1000:  # a microsecond or more: the timer's share is small
                    cases.append({"policy": policy, "isa": isa, "layer": row["index"], "name": row["name"]})
    rows = []
    timed_layers: dict[tuple[str, str], list[dict]] = {}
    for n, case in enumerate(cases):
        workload = ["forward", "--policy", f"{case['policy']}/policy.toml", "--isa", case["isa"], "--no-peak"]
        if case["layer"] is not None:
            workload = ["forward", "--policy", f"{case['policy']}/policy.toml", "--isa", case["isa"],
                        "--layer", str(case["layer"])]
        steps = 10 if case["layer"] is None else LAYER_STEPS
        model = estimate(binary, workload, "x86_64-unknown-linux-gnu", mcpu, steps=steps)
        if case["layer"] is None:
            seconds = forward_min_seconds(binary, f"{case['policy']}/policy.toml", case["isa"], 2000)
        else:
            key = (case["policy"], case["isa"])
            if key not in timed_layers:  # one timing run a plan, not one a layer
                timed_layers[key] = layer_times(binary, f"{case['policy']}/policy.toml", case["isa"], 2000)
            seconds = timed_layers[key][case["layer"]]["min_ns"] * 1e-9
        measured = seconds * ghz * 1e9
        row = {
            "policy": Path(case["policy"]).name, "isa": case["isa"],
            "workload": "whole forward" if case["layer"] is None else f"layer {case['layer']}: {case['name']}",
            "instructions": model["instructions"], "model_cycles": model["cycles"],
            "measured_cycles": round(measured), "error": model["cycles"] / measured - 1,
            "unmodelled_share": model["unmodelled_share"],
        }
        rows.append(row)
        print(f"[{n + 1}/{len(cases)}] {row['policy']} {row['isa']} {row['workload']}: model "
              f"{row['model_cycles']} cycles, measured {row['measured_cycles']}, error {row['error']:+.0%}",
              file=sys.stderr)
    errors = [r["error"] for r in rows]
    summary = {
        "host_ghz": ghz, "mcpu": mcpu, "model": llvm_mca_version(), "cases": len(rows),
        "median_error": statistics.median(errors),
        "error_p10": sorted(errors)[len(errors) // 10], "error_p90": sorted(errors)[(9 * len(errors)) // 10],
        "rows": rows,
        "method": "model: callgrind counts (steps 11 - steps 1; a layer: steps 101 - steps 1) x llvm-mca steady-state cycles per block; "
                  "measured: fastest of 2000 runs x the clock of a chain of dependent multiplications",
    }
    text = json.dumps(summary, indent=2)
    if args.out:
        Path(args.out).write_text(text + "\n")
    print(text)


def run_text(command: list[str]) -> str:
    run = subprocess.run(command, capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"cross/cycles.py: {' '.join(command)} failed:\n{run.stderr[-2000:]}")
    return run.stdout


def peak_multiply_adds_per_cycle(triple: str, mcpu: str, int8: bool) -> float:
    """The core's peak by its own model: llvm-mca's cycles for three independent chains of
    the engine's inner step on 128-bit registers (eight on the 32-bit build), float
    `mulps` + `addps` (4 multiply-adds), or int8 `pmaddubsw` + `pmaddwd` + `paddd` (16; the
    third chain accumulates in xmm0, xmm1 and xmm7 holding weights and ones)."""
    if int8:
        chain = ["movdqa %xmm0,%xmm{p}", "pmaddubsw %xmm1,%xmm{p}", "pmaddwd %xmm7,%xmm{p}", "paddd %xmm{p},%xmm{a}"]
        per_chain = 16
    else:
        chain = ["movaps %xmm0,%xmm{p}", "mulps %xmm1,%xmm{p}", "addps %xmm{p},%xmm{a}"]
        per_chain = 4
    # The chains interleaved step by step, as the kernels schedule them: the Atoms are
    # in-order, and a step waiting on the one before stalls the whole core.
    pairs = ((2, 3), (4, 5), (6, 0)) if int8 else ((2, 3), (4, 5), (6, 7))
    lines = [step.format(p=p, a=a) for step in chain for p, a in pairs]
    with tempfile.NamedTemporaryFile("w", suffix=".s", delete=False) as source:
        source.write("\n".join(lines) + "\n")
        path = source.name
    out = run_text([llvm_mca(), f"-mtriple={triple}", f"-mcpu={mcpu}", "-iterations=1000", "-all-views=false", "-summary-view", path])
    os.unlink(path)
    cycles = int(re.search(r"Total Cycles:\s+(\d+)", out).group(1)) / 1000.0
    return 3 * per_chain / cycles


def require_host_check_model() -> None:
    """Refuses a profile by another LLVM than the host check's: the robot's tick is judged by
    that check's error band (shipping_rules.pipeline_tick_ms), measured for one LLVM's core
    models, and the rule reads no profile of another."""
    check = REPO / "models" / "performance" / "host-check.json"
    if not check.is_file():
        return
    wanted = json.loads(check.read_text()).get("model")
    have = llvm_mca_version()
    if wanted and have != wanted:
        sys.exit(f"cross/cycles.py: {llvm_mca()} is {have}, but {check} was measured with {wanted}; "
                 f"install that one (Debian: apt-get install llvm-{wanted.split()[-1].split('.')[0]}) or "
                 f"check the method again with this one (python3 cross/cycles.py check --out {check})")


def profile(args) -> None:
    """A build's whole computing tick and each layer of `args.policy` on the core's model."""
    runner = args.runner.split() if args.runner else []
    policy = args.policy
    require_host_check_model()
    listing = run_text([*runner, args.binary, "--isa", args.isa, "forward", "--policy", policy, "--layers", "--steps", "1"])
    layers = json.loads(next(l for l in listing.splitlines() if l.startswith("layers "))[len("layers "):])["steps"]
    int8 = any(row["name"].startswith("int8") for row in layers)
    peak = peak_multiply_adds_per_cycle(args.triple, args.mcpu, int8)
    print(f"  whole tick ...", file=sys.stderr)
    tick = estimate(args.binary, ["--isa", args.isa, "forward", "--policy", policy, "--whole-tick"], args.triple, args.mcpu, runner,
                    steps=LAYER_STEPS)
    rows = []
    for row in layers:
        print(f"  layer {row['index']}: {row['name']} ...", file=sys.stderr)
        model = estimate(args.binary, ["--isa", args.isa, "forward", "--policy", policy, "--layer", str(row["index"])],
                         args.triple, args.mcpu, runner, steps=LAYER_STEPS)
        rows.append({
            "index": row["index"], "name": row["name"], "multiply_adds": row["multiply_adds"],
            "weight_bytes": row["weight_bytes"], "activation_bytes": row["activation_bytes"],
            "instructions": model["instructions"], "cycles": model["cycles"],
            "share_of_peak": row["multiply_adds"] / (model["cycles"] * peak) if model["cycles"] else 0.0,
        })
    directory = Path(policy).parent
    networks = tomllib.loads((directory / "policy.toml").read_text())["networks"]
    commit = run_text(["git", "-C", str(REPO), "rev-parse", "HEAD"]).strip()
    dirty = subprocess.run(["git", "-C", str(REPO), "diff", "--quiet", "HEAD", "--", "controller", "cross"]).returncode != 0
    record = {
        "build": args.build, "target": args.triple, "isa": args.isa, "mcpu": args.mcpu,
        "model": llvm_mca_version(), "ghz": args.ghz,
        "policy": directory.name, "int8": int8,
        "peak_multiply_adds_per_cycle": peak,
        "tick": {"instructions": tick["instructions"], "cycles": tick["cycles"],
                 "instructions_per_cycle": tick["instructions_per_cycle"],
                 "unmodelled_share": tick["unmodelled_share"], "hottest_blocks": tick["hottest_blocks"][:5]},
        "layers": rows,
        "networks_sha256": [hashlib.sha256((directory / n).read_bytes()).hexdigest() for n in networks],
        "commit": commit + (" (with uncommitted changes)" if dirty else ""),
        "method": "callgrind counts of one step (a tick or a layer: 101 steps - 1, over a hundred) x llvm-mca "
                  "steady-state cycles per block (cross/cycles.py); no cache misses or mispredicted branches",
    }
    Path(args.out).write_text(json.dumps(record, indent=2) + "\n")
    ms = tick["cycles"] / (args.ghz * 1e6)
    print(f"  tick: {tick['instructions']} instructions, {tick['cycles']} cycles "
          f"({tick['instructions_per_cycle']:.2f} a cycle), {ms:.3f} ms at {args.ghz} GHz", file=sys.stderr)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    est = sub.add_parser("estimate", help="cycles of one step of a workload on a core's model")
    est.add_argument("--binary", required=True)
    est.add_argument("--triple", default="x86_64-unknown-linux-gnu")
    est.add_argument("--mcpu", required=True, help="llvm-mca's core: atom (V5), silvermont (V6), ...")
    est.add_argument("--runner", default="", help="a program to run the binary with (the i686 loader)")
    est.add_argument("workload", nargs=argparse.REMAINDER, help="-- then the binary's arguments")
    prof = sub.add_parser("profile", help="a build's tick and each layer on its core's model (cross/cycles)")
    prof.add_argument("--binary", required=True)
    prof.add_argument("--runner", default="")
    prof.add_argument("--triple", required=True)
    prof.add_argument("--mcpu", required=True)
    prof.add_argument("--ghz", type=float, required=True, help="the core's clock, for milliseconds")
    prof.add_argument("--isa", required=True)
    prof.add_argument("--build", required=True, help="v5 or v6")
    prof.add_argument("--policy", required=True)
    prof.add_argument("--out", required=True)
    chk = sub.add_parser("check", help="the method against measured time on this host")
    chk.add_argument("--binary", default=os.path.expanduser("~/.cache/dribble/target/release/dribble-controller"))
    chk.add_argument("--mcpu", default=None, help="this CPU's model (default: from /proc/cpuinfo)")
    chk.add_argument("--out", default=None)
    args = parser.parse_args()
    if args.command == "estimate":
        workload = [w for w in args.workload if w != "--"] if args.workload[:1] == ["--"] else args.workload
        runner = args.runner.split() if args.runner else None
        print(json.dumps(estimate(args.binary, workload, args.triple, args.mcpu, runner), indent=2))
    elif args.command == "profile":
        profile(args)
    else:
        check(args)


if __name__ == "__main__":
    main()
