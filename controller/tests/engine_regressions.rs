//! Replays the engine fuzzer's findings (`tests/fuzz/regressions/engine/`, written by
//! `controller/examples/fuzz_engine.rs` and `scripts/fuzz engine`): each graph is compared
//! with tract on every instruction set this CPU runs. It must neither panic nor disagree:
//! the engine computes it as tract does, or refuses it (and tract runs it).

mod support;

use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::engine::oracle::{Comparison, compare};
use tract_onnx::prelude::Framework;

#[test]
fn every_graph_the_fuzzer_found_is_computed_as_tract_does_or_refused() {
    let corpus = support::package_dir().join("../tests/fuzz/regressions/engine");
    let mut files: Vec<_> = std::fs::read_dir(&corpus)
        .unwrap_or_else(|error| panic!("{}: {error}", corpus.display()))
        .filter_map(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| path.extension().is_some_and(|e| e == "onnx"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no regressions in {}", corpus.display());
    for path in &files {
        let bytes = std::fs::read(path).expect("read");
        let model = tract_onnx::onnx()
            .proto_model_for_read(&mut &bytes[..])
            .unwrap_or_else(|error| panic!("{}: {error}", path.display()));
        let shapes = std::fs::read_to_string(path.with_extension("inputs")).expect(".inputs file");
        let inputs: Vec<(String, Vec<usize>)> = shapes
            .lines()
            .filter(|line| !line.trim().is_empty())
            .map(|line| {
                let mut words = line.split_whitespace();
                let name = words.next().expect("a name").to_owned();
                let shape = words.map(|d| d.parse().expect("a dimension")).collect();
                (name, shape)
            })
            .collect();
        let inputs: Vec<(&str, &[usize])> = inputs
            .iter()
            .map(|(name, shape)| (name.as_str(), shape.as_slice()))
            .collect();
        for isa in Isa::available() {
            let comparison = compare(&model, &inputs, isa, 1, 2);
            println!("{} ({isa}): {comparison:?}", path.display());
            assert!(
                !matches!(comparison, Comparison::Disagree(_)),
                "{} ({isa}): {comparison:?}",
                path.display()
            );
        }
    }
}
