"""The book's page on B-Human's CompiledNN beside dribble's engine (issue 49), generated from
the file `python -m dribble_models.compiled_nn compare` leaves:

    python -m dribble_models.compiled_nn_report     # print the page
    python -m dribble_models.book --write            # writes it with the other generated pages
"""

from __future__ import annotations

import json
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parents[2]
RESULT = REPOSITORY / "models" / "performance" / "compiled-nn.json"


def _us(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


def _count(value: int | None) -> str:
    return "-" if value is None else f"{value:,}"


def _network(row: dict) -> str:
    """The row's role and the model directory measured: the shipped models change, the role
    stays (`models/fixtures/cnn` is named by its role alone)."""
    policy = row.get("policy", "models/fixtures/")
    return row["network"] if policy.startswith("models/fixtures/") else f"{row['network']} (`{Path(policy).name}`)"


def table(result: dict) -> list[str]:
    lines = [
        "| network | instruction set | CompiledNN µs | dribble µs | CompiledNN / dribble | "
        "CompiledNN instructions | dribble instructions | CompiledNN's command = onnxruntime's |",
        "|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for row in result["rows"]:
        for entry in row["engines"]:
            theirs = entry.get("compiled_nn_us")
            ours = entry["dribble_us"]
            ratio = f"{theirs / ours:.2f}" if theirs else "-"
            isa = entry["isa"] + (" int8" if entry.get("int8") else "")
            agreement = entry.get("compiled_nn_vs_onnxruntime")
            agrees = "-" if not agreement else (
                f"{'yes' if agreement['equal'] else 'NO'} (max difference {agreement['max_abs_difference']:.1e}, "
                f"{agreement['cases']} inputs)")
            lines.append(
                f"| {_network(row)} | {isa} | {_us(theirs)} | {_us(ours)} | {ratio} | "
                f"{_count(entry.get('compiled_nn_instructions'))} | {_count(entry.get('dribble_instructions'))} | "
                f"{agrees} |")
    return lines


def verdicts(result: dict) -> list[str]:
    """The issue's targets, read off the rows."""
    slower = [(row["network"], e["isa"]) for row in result["rows"] for e in row["engines"]
              if e.get("compiled_nn_us") and e["dribble_us"] >= e["compiled_nn_us"]]
    int8_vs_float = []
    for row in result["rows"]:
        best_float = min((e["compiled_nn_us"] for e in row["engines"] if e.get("compiled_nn_us")), default=None)
        for e in row["engines"]:
            if e.get("int8") and best_float is not None:
                int8_vs_float.append((row["network"], e["isa"], e["dribble_us"] < best_float))
    lines = []
    if slower:
        lines.append("Our float engine is slower than CompiledNN on: "
                     + ", ".join(f"{network} ({isa})" for network, isa in slower) + ".")
    else:
        lines.append("Our float engine is faster than CompiledNN on every network at every instruction set measured.")
    if int8_vs_float:
        missed = [f"{network} ({isa})" for network, isa, faster in int8_vs_float if not faster]
        lines.append("Our int8 engine is faster than CompiledNN's fastest float pass on every int8 row."
                     if not missed else "Our int8 engine is not faster than CompiledNN's fastest float pass on: "
                     + ", ".join(missed) + ".")
    return lines


def _widest(row: dict) -> str:
    """The widest instruction set a row measured (the comparison lists them narrowest first)."""
    return [e["isa"] for e in row["engines"] if not e.get("int8")][-1]


def _beside_onnxruntime(row: dict) -> list[tuple[str, float | None, float | None]]:
    """(float or int8, onnxruntime's µs, ours on the row's widest set): onnxruntime picks its
    own kernels from the CPU and cannot be kept to SSE."""
    widest = _widest(row)
    ours = {bool(e.get("int8")): e["dribble_us"] for e in row["engines"] if e["isa"] == widest}
    theirs = row["onnxruntime"]
    return [("float", theirs.get("float_us"), ours.get(False)), ("int8", theirs.get("int8_us"), ours.get(True))]


def onnxruntime_table(result: dict) -> list[str]:
    """onnxruntime beside our widest instruction set, float and int8."""
    rows = [row for row in result["rows"] if row.get("onnxruntime")]
    if not rows:
        return []
    lines = [
        f"Beside {result.get('onnxruntime', 'onnxruntime')}, our engine on its widest set measured "
        f"({_widest(rows[0])}):",
        "",
        "| network | onnxruntime float µs | dribble float µs | onnxruntime int8 µs | dribble int8 µs |",
        "|---|---:|---:|---:|---:|",
    ]
    for row in rows:
        (_, float_theirs, float_ours), (_, int8_theirs, int8_ours) = _beside_onnxruntime(row)
        lines.append(f"| {_network(row)} | {_us(float_theirs)} | {_us(float_ours)} | "
                     f"{_us(int8_theirs)} | {_us(int8_ours)} |")
    return lines


def onnxruntime_verdicts(result: dict) -> list[str]:
    rows = [row for row in result["rows"] if row.get("onnxruntime")]
    if not rows:
        return []
    slower = [f"{row['network']} ({kind})" for row in rows for kind, theirs, ours in _beside_onnxruntime(row)
              if theirs is not None and ours is not None and ours >= theirs]
    return ["Our engine is faster than onnxruntime on every network, float and int8."] if not slower else [
        "Our engine is not faster than onnxruntime on: " + ", ".join(slower) + "."]


def page() -> str:
    lines = [
        "# CompiledNN beside the engine",
        "",
        "<!-- generated by python -m dribble_models.book --write from models/performance/compiled-nn.json "
        "(python -m dribble_models.compiled_nn compare) -->",
        "",
        "B-Human's CompiledNN is the engine SPL teams run on the Nao (B-Human's own code; HULKs' through the "
        "`compiled-nn` crate): a JIT that writes SSSE3 / SSE4 (and AVX2) code for a Keras network when it "
        "loads it. The sources the `compiled-nn-bindings` crate carries are built by `scripts/setup "
        "--compiled-nn` with their Keras HDF5 front end: their ONNX reader parses the file and then fails "
        "with \"Not yet implemented\", so `python -m dribble_models.compiled_nn export` writes each ONNX CNN "
        "as the Keras model that computes the same function (symmetric padding as a `ZeroPadding2D` layer "
        "before a `valid` convolution, the first dense layer's columns reordered for channels-last "
        "flattening). The last column checks that the file is the same network. CompiledNN has no int8 "
        "path; the int8 rows are ours alone.",
        "",
    ]
    if not RESULT.exists():
        return "\n".join(lines + ["No comparison has been run on this tree yet.", ""])
    result = json.loads(RESULT.read_text())
    lines += [
        f"Measured on {result['cpu']}, one thread, {result['steps']} passes a run: {result['method']}.",
        "",
        *table(result),
        "",
        *verdicts(result),
        "",
    ]
    if onnxruntime := onnxruntime_table(result):
        lines += [*onnxruntime, "", *onnxruntime_verdicts(result), ""]
    return "\n".join(lines)


def main() -> None:
    print(page(), end="")


if __name__ == "__main__":
    main()
