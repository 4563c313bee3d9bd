//! tract as the engine's oracle on any graph: lower a model for one instruction set, run the
//! plan and tract on the same pseudo-random inputs, and say whether they agree.
//!
//! The property tests of the lowering, the structure-aware fuzz target and the regression
//! corpus all ask this one question, so the answer is defined once. The controller's own
//! load check (`learned/load_check.rs`) asks it of the networks it is about to run, through
//! the ports the manifest names.

use std::panic::{AssertUnwindSafe, catch_unwind};

use tract_onnx::pb;
use tract_onnx::prelude::*;

use super::{CompiledNetwork, Isa};

/// How far the engine may differ from tract: relative to `1 +` the largest magnitude in
/// tract's output tensor. The summation orders differ, and a long sum's rounding grows with
/// the size of its terms, not of its result (a 4800-long Gemm row whose terms cancel to 0.05
/// differs by 1e-4 under FMA: fuzz seed 38777); the shipped models differ by at most a few
/// 1e-6, a wrong lowering by far more.
pub const TOLERANCE: f32 = 1e-4;

/// The same for a plan with int8 steps (a QDQ graph). tract and the engine compute the
/// integer sums alike, but a float product that lands within rounding of half a grid step
/// can take the neighbouring step in one and not the other, and that step is carried
/// through the layers after it: a few 1e-3 on the networks' outputs, where a wrong
/// lowering (a wrong zero point, scale or layout) is off by tenths.
pub const INT8_TOLERANCE: f32 = 2e-2;

/// What comparing the engine with tract on one model found.
#[derive(Clone, Debug, PartialEq)]
pub enum Comparison {
    /// tract cannot run the model (nothing to compare).
    TractRefuses(String),
    /// The engine refuses to lower the model (tract runs it in the controller).
    EngineRefuses(String),
    /// Every output value within the plan's tolerance ([`TOLERANCE`], [`INT8_TOLERANCE`]);
    /// the largest difference seen.
    Agree { largest_difference: f32 },
    /// An output differs (a finding: the controller's load check would fall back to tract,
    /// but the lowering computed something else than the graph says).
    Disagree(String),
}

/// Two values agree: equal (infinities included), both NaN, or within `tolerance` (the
/// plan's, [`CompiledNetwork::tolerance`]) of an output tensor whose largest finite
/// magnitude is `scale`.
pub fn agree(engine: f32, tract: f32, scale: f32, tolerance: f32) -> bool {
    engine == tract
        || (engine.is_nan() && tract.is_nan())
        || (engine - tract).abs() <= tolerance * (1.0 + scale)
}

/// A disagreement described by `describe(engine's, other's)` when the two lengths differ.
fn lengths_differ(
    engine: usize,
    other: usize,
    describe: impl FnOnce(usize, usize) -> String,
) -> Option<Comparison> {
    (engine != other).then(|| Comparison::Disagree(describe(engine, other)))
}

/// The largest finite magnitude in `values` (0 when none is finite): the `scale` of
/// [`agree`].
pub fn scale(values: &[f32]) -> f32 {
    values
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0, |largest, v| largest.max(v.abs()))
}

/// Runs `model` (inputs of the given names and shapes, all f32) under tract and under the
/// engine with `isa`'s kernels (tract first: a graph tract refuses or panics on is
/// [`Comparison::TractRefuses`]; a panic of the engine is not caught here) on `runs` pseudo-random inputs drawn from `seed` (values in
/// [-2, 2]), comparing the graph's outputs in order. The plan runs `runs` times in a row, as
/// the controller runs it.
pub fn compare(
    model: &pb::ModelProto,
    inputs: &[(&str, &[usize])],
    isa: Isa,
    seed: u64,
    runs: usize,
) -> Comparison {
    // The controller's loader refuses these before tract sees them (tract hangs on some).
    if let Err(why) = crate::policy::model_limits::check(model) {
        return Comparison::TractRefuses(format!("the loader refuses it: {why}"));
    }
    // tract panics on some hostile graphs; the controller's loader contains that (it runs
    // inside a panic guard), so here it is tract refusing, not a finding about the engine.
    let plan = match catch_unwind(AssertUnwindSafe(|| tract_plan(model, inputs))) {
        Ok(Ok(plan)) => plan,
        Ok(Err(error)) => return Comparison::TractRefuses(format!("{error:#}")),
        Err(_) => return Comparison::TractRefuses("tract panicked while planning".into()),
    };
    let mut compiled =
        match CompiledNetwork::lower(std::path::Path::new("oracle"), model, inputs, isa) {
            Ok(compiled) => compiled,
            Err(why) => return Comparison::EngineRefuses(why.0),
        };
    let output_names: Vec<String> = model
        .graph
        .iter()
        .flat_map(|graph| graph.output.iter().map(|output| output.name.clone()))
        .collect();
    let mut state = seed | 1;
    let mut largest_difference = 0.0f32;
    for run in 0..runs {
        let mut tensors = TVec::new();
        for (name, shape) in inputs {
            let values: Vec<f32> = (0..shape.iter().product::<usize>())
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state >> 40) as f32 / (1u64 << 22) as f32 - 2.0
                })
                .collect();
            let Some(input) = compiled.input_mut(name) else {
                return Comparison::Disagree(format!("the plan has no input {name}"));
            };
            if let Some(disagree) = lengths_differ(input.len(), values.len(), |plan, given| {
                format!("the plan's input {name} holds {plan} values, not {given}")
            }) {
                return disagree;
            }
            input.copy_from_slice(&values);
            match Tensor::from_shape(shape, &values) {
                Ok(tensor) => tensors.push(tensor.into_tvalue()),
                Err(error) => return Comparison::TractRefuses(format!("{error:#}")),
            }
        }
        let expected = match catch_unwind(AssertUnwindSafe(|| plan.run(tensors))) {
            Ok(Ok(outputs)) => outputs,
            Ok(Err(error)) => return Comparison::TractRefuses(format!("{error:#}")),
            Err(_) => return Comparison::TractRefuses("tract panicked while running".into()),
        };
        compiled.run();
        for (name, value) in output_names.iter().zip(&expected) {
            let as_floats = value.cast_to::<f32>().ok().and_then(|tensor| {
                let view = tensor.try_as_plain_ram().ok()?;
                view.as_slice::<f32>().ok().map(<[f32]>::to_vec)
            });
            let Some(tract) = as_floats else {
                return Comparison::TractRefuses(format!("output {name} is not numbers"));
            };
            let Some(engine) = compiled.output(name) else {
                return Comparison::Disagree(format!("the plan has no output {name}"));
            };
            if let Some(disagree) = lengths_differ(engine.len(), tract.len(), |engine, tract| {
                format!("output {name}: {engine} values from the engine, {tract} from tract")
            }) {
                return disagree;
            }
            let scale = scale(&tract);
            for (i, (&a, &b)) in engine.iter().zip(&tract).enumerate() {
                if !agree(a, b, scale, compiled.tolerance()) {
                    return Comparison::Disagree(format!(
                        "output {name}[{i}] is {a} from the engine, {b} from tract (run {run})"
                    ));
                }
                if a.is_finite() && b.is_finite() {
                    largest_difference = largest_difference.max((a - b).abs());
                }
            }
        }
    }
    Comparison::Agree { largest_difference }
}

type Plan = std::sync::Arc<TypedRunnableModel>;

/// tract's plan for `model` with the given input shapes, as the controller makes it.
fn tract_plan(model: &pb::ModelProto, inputs: &[(&str, &[usize])]) -> TractResult<Plan> {
    let mut inference = tract_onnx::onnx().model_for_proto_model(model)?;
    let names: Vec<String> = inference
        .input_outlets()?
        .iter()
        .map(|outlet| inference.node(outlet.node).name.clone())
        .collect();
    for (index, name) in names.iter().enumerate() {
        let (_, shape) = inputs
            .iter()
            .find(|(n, _)| n == name)
            .ok_or_else(|| anyhow::anyhow!("no shape for input {name}"))?;
        inference.set_input_fact(index, f32::fact(*shape).into())?;
    }
    inference.into_optimized()?.into_runnable()
}
