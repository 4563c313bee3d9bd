"""A modal CNN that the controller commits to: its hypotheses as outputs and a switch margin.

The modal CNN (`networks.ModalCNN`) is exported with its choice inside the graph: the
hypothesis with the largest logit, afresh at every frame. Where two hypotheses are nearly
equal (which side to search, which way to circle the ball) that choice can flip between
frames and the robot dithers. This writes a copy of a modal policy whose ONNX file also
outputs every hypothesis's command (`hypotheses`, [1, K, 3]) and the choice logits
(`logits`, [1, K]), and whose manifest carries a `[hypotheses]` table with a switch margin:
the controller (`controller/src/policy/commitment.rs`) then keeps the hypothesis it chose
until another's logit beats it by more than the margin. The weights are the same bytes; the
graph's own `command` output is kept, so margin 0 gives its commands.

    python -m dribble_models.commitment --policy models/policy/cnn-modal-observable \\
        --margin 1.0 --out models/policy/cnn-modal-committed-observable
"""

from __future__ import annotations

import argparse
import shutil
import tomllib
from pathlib import Path

import onnx
from onnx import TensorProto, helper

HYPOTHESES_OUTPUT = "hypotheses"
LOGITS_OUTPUT = "logits"


def _producer_of_weight(graph: onnx.GraphProto, weight: str) -> onnx.NodeProto:
    found = [node for node in graph.node if node.op_type == "Gemm" and weight in node.input]
    if len(found) != 1:
        raise SystemExit(f"expected one Gemm reading {weight!r}, found {len(found)}: is this a modal CNN?")
    return found[0]


def add_hypothesis_outputs(model: onnx.ModelProto) -> int:
    """Adds the `hypotheses` and `logits` outputs to a modal CNN's graph; returns K."""
    graph = model.graph
    names = {output.name for output in graph.output}
    if HYPOTHESES_OUTPUT in names or LOGITS_OUTPUT in names:
        raise SystemExit("the graph already has hypotheses outputs")
    hypotheses_gemm = _producer_of_weight(graph, "hypotheses.weight")
    choice_gemm = _producer_of_weight(graph, "choice.weight")
    choice_weight = next(t for t in graph.initializer if t.name == "choice.weight")
    count = int(choice_weight.dims[0])
    reshaped = [
        node
        for node in graph.node
        if node.op_type == "Reshape" and node.input and node.input[0] == hypotheses_gemm.output[0]
    ]
    if len(reshaped) != 1:
        raise SystemExit("the hypotheses are not reshaped to [B, K, 3] once")
    graph.node.extend(
        [
            helper.make_node("Identity", [reshaped[0].output[0]], [HYPOTHESES_OUTPUT], name="/hypotheses_output"),
            helper.make_node("Identity", [choice_gemm.output[0]], [LOGITS_OUTPUT], name="/logits_output"),
        ]
    )
    graph.output.extend(
        [
            helper.make_tensor_value_info(HYPOTHESES_OUTPUT, TensorProto.FLOAT, [1, count, 3]),
            helper.make_tensor_value_info(LOGITS_OUTPUT, TensorProto.FLOAT, [1, count]),
        ]
    )
    onnx.checker.check_model(model, full_check=True)
    return count


def hypotheses_table(count: int, margin: float) -> str:
    return "\n".join(
        [
            "# The controller commits to one command hypothesis: it keeps the one it chose until",
            "# another's choice logit beats it by more than switch_margin (controller/src/policy/",
            "# commitment.rs); 0 takes the largest logit every frame, as the `command` output does.",
            "[hypotheses]",
            f"count = {count}",
            f'commands = "{HYPOTHESES_OUTPUT}"',
            f'logits = "{LOGITS_OUTPUT}"',
            f"switch_margin = {float(margin)!r}",
            "",
            "",
        ]
    )


def write_committed(policy: Path, margin: float, out: Path) -> Path:
    """Writes the committed copy of the modal policy in `policy` to `out`; returns its manifest."""
    if margin < 0:
        raise SystemExit("--margin must not be negative")
    manifest_text = (policy / "policy.toml").read_text()
    manifest = tomllib.loads(manifest_text)
    if manifest.get("kind") != "cnn" or manifest.get("networks") != ["policy.onnx"] or "hypotheses" in manifest:
        raise SystemExit(f"{policy} is not a modal CNN policy of one network without a [hypotheses] table")
    model = onnx.load(str(policy / "policy.onnx"))
    count = add_hypothesis_outputs(model)
    if "\n[training]\n" not in manifest_text:
        raise SystemExit(f"{policy / 'policy.toml'} has no [training] table")
    committed = manifest_text.replace("\n[training]\n", "\n" + hypotheses_table(count, margin) + "[training]\n", 1)
    if tomllib.loads(committed)["hypotheses"]["switch_margin"] != float(margin):
        raise SystemExit("the written manifest does not read back")
    out.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(out / "policy.onnx"))
    (out / "policy.toml").write_text(committed)
    # The same training: its loss curve. Errors on recorded episodes (score_*.json) depend
    # on the commitment's state and are measured again by `dribble score`.
    if (policy / "loss_curve.png").exists():
        shutil.copyfile(policy / "loss_curve.png", out / "loss_curve.png")
    return out / "policy.toml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", type=Path, required=True, help="a modal CNN's model directory")
    parser.add_argument("--margin", type=float, required=True, help="the switch margin, in choice logits")
    parser.add_argument("--out", type=Path, required=True, help="the committed copy's model directory")
    args = parser.parse_args()
    print(write_committed(args.policy, args.margin, args.out))


if __name__ == "__main__":
    main()
