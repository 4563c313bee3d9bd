"""`[lineage]` in the manifests: what a model came from, written by the trainer and the
quantizer, and every committed reference still naming the model it did."""

import hashlib
import tomllib
from pathlib import Path

from dribble_models.manifest import Lineage, Manifest, ModelReference, TrainingRecord
from dribble_models.quantize import with_precision
from dribble_models.shipped_weights import network_of

REPOSITORY = Path(__file__).resolve().parents[2]
POLICIES = REPOSITORY / "models" / "policy"


def test_a_lineage_is_written_before_the_training_record_and_reads_back():
    lineage = Lineage(ModelReference("models/policy/a", "0123456789ab", "pruned"), ModelReference("models/policy/b", "ba9876543210"), former_names=["old-name"])
    text = Manifest("cnn", ["policy.onnx"], TrainingRecord("train", 3), lineage=lineage).to_toml()
    read = tomllib.loads(text)
    assert read["lineage"] == {
        "started_from": {"model": "models/policy/a", "sha256": "0123456789ab", "how": "pruned"},
        "distilled_from": {"model": "models/policy/b", "sha256": "ba9876543210"},
        "former_names": ["old-name"],
    }
    assert text.index("[lineage]") < text.index("[training]")
    assert "lineage" not in tomllib.loads(Manifest("cnn", ["policy.onnx"], TrainingRecord("train", 3)).to_toml())


def test_an_int8_copy_keeps_the_lineage_but_not_the_float_models_former_names():
    lineage = Lineage(ModelReference("models/policy/a", "0123456789ab"), former_names=["float-name"])
    text = with_precision(Manifest("cnn", ["policy.onnx"], TrainingRecord("train", 3), lineage=lineage).to_toml(), "int8")
    read = tomllib.loads(text)
    assert read["precision"] == "int8"
    assert read["lineage"] == {"started_from": {"model": "models/policy/a", "sha256": "0123456789ab"}}


def test_every_committed_reference_names_the_model_it_did():
    """A model referred to under models/policy exists and its network still has the hash the
    reference recorded (a rename that missed a manifest, or a retrained parent, fails here)."""
    checked = 0
    for manifest in sorted(POLICIES.glob("*/policy.toml")):
        lineage = tomllib.loads(manifest.read_text()).get("lineage", {})
        for key in ("started_from", "distilled_from", "features_from"):
            reference = lineage.get(key)
            if reference is None or not reference["model"].startswith("models/policy/"):
                continue  # a checkpoint under ~/.cache: named by its hash only
            parent = REPOSITORY / reference["model"]
            assert (parent / "policy.toml").is_file(), f"{manifest}: {key} {parent} is gone"
            digest = hashlib.sha256(network_of(parent).read_bytes()).hexdigest()
            assert digest.startswith(reference["sha256"]), f"{manifest}: {key} {parent} is another model now"
            checked += 1
    assert checked >= 22


def test_former_names_are_not_taken_by_another_model():
    names = {path.parent.name for path in POLICIES.glob("*/policy.toml")}
    for manifest in POLICIES.glob("*/policy.toml"):
        for former in tomllib.loads(manifest.read_text()).get("lineage", {}).get("former_names", []):
            assert former not in names, f"{manifest.parent.name}'s former name {former} names a model again"


def test_the_trainer_records_the_models_a_run_came_from():
    from types import SimpleNamespace

    from dribble_models.training_record import lineage_of

    parent = Path("models/policy") / (POLICIES / "HOST_MODEL").read_text().strip()
    digest = hashlib.sha256(network_of(REPOSITORY / parent).read_bytes()).hexdigest()[:12]
    run = SimpleNamespace(init_from=None, prune_from=REPOSITORY / parent, distill_from=REPOSITORY / parent, features_from=None, freeze_features=False)
    lineage = lineage_of(run)
    assert lineage.started_from.sha256 == digest and lineage.started_from.how.startswith("pruned")
    assert lineage.distilled_from.sha256 == digest and lineage.features_from is None
    assert lineage_of(SimpleNamespace(init_from=None, prune_from=None, distill_from=None, features_from=None, freeze_features=False)) is None
