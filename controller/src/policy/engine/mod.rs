//! The compiled policy engine: the controller's own executor for the paper's networks, with
//! nothing allocated after load and kernels compiled for the CPU it runs on.
//!
//! tract stays the loader and the oracle: it reads the ONNX file, checks it against the
//! manifest and plans it, as before; the same file's graph is then lowered ([`lower`]) into
//! a static plan ([`plan`]) whose every buffer is allocated here, with weights re-laid out
//! for the kernels ([`kernels`]), compiled once per instruction set ([`isa`]). A graph with
//! an operator or shape the engine does not lower runs under tract, and the reason is kept
//! for the controller to log at load.
//!
//! Layers, each importing only those below it: `layout` (buffers and weight layouts,
//! importing nothing of the engine), `kernels` (the arithmetic per instruction set), `plan`
//! (the steps and their run loop), `lower` (ONNX to a plan, one file per operator family)
//! and this module (the public API and the per-instruction-set entry points).
//!
//! Why our own instead of a library: tract plans and allocates on every run (84 allocations,
//! 932 KB per CNN step) and its maintainers do not aim at real-time use; the other Rust
//! runtimes wrap C++ (onnxruntime) or need a GPU. B-Human met the same wall on the Nao and
//! wrote CompiledNN; this is the same idea, smaller, for the operators these networks use.

pub mod isa;
mod kernels;
mod layout;
mod lower;
pub mod onnx_builder;
pub mod oracle;
pub mod peak;
mod plan;
#[cfg(test)]
mod proptest;

use std::path::{Path, PathBuf};

use tract_onnx::pb;

pub use isa::Isa;
pub use lower::{MAX_ELEMENTS, MAX_PLAN_ELEMENTS, Unsupported};

use layout::BufferId;
use plan::Step;

/// One step of a plan as a per-layer table shows it ([`CompiledNetwork::step_reports`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StepReport {
    /// The operator, and for layers with weights their kernel and channels.
    pub name: String,
    pub multiply_adds: u64,
    /// The weights read each run (4 bytes a float, 1 an int8 code).
    pub weight_bytes: u64,
    /// The float buffers the step reads and writes (4 bytes a value).
    pub activation_bytes: u64,
}

/// A network lowered to a static plan for one instruction set.
#[derive(Debug)]
pub struct CompiledNetwork {
    path: PathBuf,
    isa: Isa,
    steps: Vec<Step>,
    buffers: Vec<Vec<f32>>,
    /// Scratch for the dense layers' lists of non-zero inputs.
    nonzero: Vec<u32>,
    inputs: Vec<(String, BufferId)>,
    outputs: Vec<(String, BufferId, usize)>,
}

impl CompiledNetwork {
    /// Lowers `model`'s graph (the file at `path`) for inputs of the given names and shapes,
    /// to run with `isa`'s kernels. `isa` must be available on this CPU.
    pub(crate) fn lower(
        path: &Path,
        model: &pb::ModelProto,
        inputs: &[(&str, &[usize])],
        isa: Isa,
    ) -> Result<Self, Unsupported> {
        if !isa.is_available() {
            return Err(Unsupported(format!("this CPU cannot run {isa} kernels")));
        }
        let lowering = lower::lower(
            model,
            inputs,
            isa.dense_panel_width(),
            isa.winograd_fit(),
            isa.int8_kernel(),
        )?;
        let mut buffers = lowering.buffers;
        // Constants folded into the steps (weights, biases) need no buffer of their own.
        let mut used = vec![false; buffers.len()];
        for step in &lowering.steps {
            let (reads, writes) = step.buffers();
            for id in reads.into_iter().chain(writes) {
                used[id] = true;
            }
        }
        for &(_, id) in &lowering.inputs {
            used[id] = true;
        }
        for &(_, id, _) in &lowering.outputs {
            used[id] = true;
        }
        for (buffer, used) in buffers.iter_mut().zip(used) {
            if !used {
                *buffer = Vec::new();
            }
        }
        let widest_dense = lowering
            .steps
            .iter()
            .filter_map(|step| match step {
                Step::Dense { weights, .. } | Step::Lstm { weights, .. } => Some(weights.inputs()),
                _ => None,
            })
            .max()
            .unwrap_or(0);
        Ok(Self {
            path: path.to_owned(),
            isa,
            steps: lowering.steps,
            buffers,
            nonzero: vec![0; widest_dense],
            inputs: lowering.inputs,
            outputs: lowering.outputs,
        })
    }

    pub fn isa(&self) -> Isa {
        self.isa
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The input named `name`, to be written before [`Self::run`].
    pub fn input_mut(&mut self, name: &str) -> Option<&mut [f32]> {
        let id = self.inputs.iter().find(|(n, _)| n == name)?.1;
        Some(&mut self.buffers[id])
    }

    /// The output named `name`, as the last [`Self::run`] left it.
    pub fn output(&self, name: &str) -> Option<&[f32]> {
        let &(_, id, len) = self.outputs.iter().find(|(n, _, _)| n == name)?;
        Some(&self.buffers[id][..len])
    }

    /// Copies output `from` into input `to` (a recurrent state carried to the next step).
    pub fn carry(&mut self, from: &str, to: &str) -> bool {
        let (Some(&(_, source, len)), Some(&(_, target))) = (
            self.outputs.iter().find(|(n, _, _)| n == from),
            self.inputs.iter().find(|(n, _)| n == to),
        ) else {
            return false;
        };
        if source == target || self.buffers[target].len() != len {
            return false;
        }
        let values = std::mem::take(&mut self.buffers[target]);
        let mut values = values;
        values.copy_from_slice(&self.buffers[source][..len]);
        self.buffers[target] = values;
        true
    }

    /// How many of its steps compute in integers (a QDQ graph's int8 convolutions and dense
    /// layers); 0 for a float graph.
    pub fn int8_steps(&self) -> usize {
        self.steps
            .iter()
            .filter(|step| matches!(step, Step::QuantizedConv(_) | Step::QuantizedDense(_)))
            .count()
    }

    /// How far its outputs may differ from tract's on the same graph and input
    /// ([`oracle::TOLERANCE`], [`oracle::INT8_TOLERANCE`] for a plan that rounds onto grids).
    pub fn tolerance(&self) -> f32 {
        let grids = self.steps.iter().any(|step| {
            matches!(
                step,
                Step::QuantizedConv(_) | Step::QuantizedDense(_) | Step::SnapToGrid { .. }
            )
        });
        if grids {
            oracle::INT8_TOLERANCE
        } else {
            oracle::TOLERANCE
        }
    }

    /// How many steps the plan has.
    pub fn steps(&self) -> usize {
        self.steps.len()
    }

    /// How many convolutions run by Winograd's minimal filtering ([`winograd`]) rather than
    /// as direct sums: they round differently, so a closed loop's episodes belong to one or
    /// the other.
    pub fn winograd_layers(&self) -> usize {
        self.steps
            .iter()
            .filter(|step| {
                matches!(
                    step,
                    Step::Conv {
                        winograd: Some(_),
                        ..
                    }
                )
            })
            .count()
    }

    /// The multiply-adds of one run: the arithmetic that bounds its time from below (see
    /// [`peak`]).
    pub fn multiply_adds(&self) -> u64 {
        self.steps.iter().map(Step::multiply_adds).sum()
    }

    /// Wall time of each step over `repeats` runs (after a tenth as many to warm the caches
    /// up) and its multiply-adds, for profiling (allocates its report).
    pub fn profile(&mut self, repeats: u32) -> Vec<(String, std::time::Duration, u64)> {
        let mut report = Vec::new();
        for i in 0..self.steps.len() {
            for _ in 0..repeats / 10 {
                execute(
                    self.isa,
                    &mut self.steps[i..i + 1],
                    &mut self.buffers,
                    &mut self.nonzero,
                );
            }
            let started = std::time::Instant::now();
            for _ in 0..repeats {
                execute(
                    self.isa,
                    &mut self.steps[i..i + 1],
                    &mut self.buffers,
                    &mut self.nonzero,
                );
            }
            let name = format!("{:?}", self.steps[i]).chars().take(60).collect();
            report.push((
                name,
                started.elapsed() / repeats,
                self.steps[i].multiply_adds(),
            ));
        }
        report
    }

    /// Runs step `index` of the plan alone, on the buffers as the last run left them: one
    /// layer's workload for timing and instruction counts (`dribble-controller forward
    /// --layer`). Allocates nothing. `index` must be below [`Self::steps`].
    pub fn run_step(&mut self, index: usize) {
        execute(
            self.isa,
            &mut self.steps[index..index + 1],
            &mut self.buffers,
            &mut self.nonzero,
        );
    }

    /// Each step's name, multiply-adds and bytes (its weights, and the float buffers it
    /// reads and writes), for per-layer tables.
    pub fn step_reports(&self) -> Vec<StepReport> {
        self.steps
            .iter()
            .map(|step| {
                let (reads, writes) = step.buffers();
                let activations: usize = reads
                    .iter()
                    .chain(&writes)
                    .map(|&id| self.buffers[id].len())
                    .sum();
                StepReport {
                    name: step.describe(),
                    multiply_adds: step.multiply_adds(),
                    weight_bytes: step.weight_bytes(),
                    activation_bytes: 4 * activations as u64,
                }
            })
            .collect()
    }

    /// Runs the plan on the inputs as they are. Allocates nothing.
    pub fn run(&mut self) {
        execute(
            self.isa,
            &mut self.steps,
            &mut self.buffers,
            &mut self.nonzero,
        );
    }
}

// Calling the kernels compiled for an instruction set is sound only on a CPU that has it.
// (The kernels' own `unsafe` blocks, in `kernels::{simd, winograd, window_asm}`, rest on bounds
// each kernel checks once before its loops, with checked arithmetic.)
#[allow(unsafe_code)]
fn execute(isa: Isa, steps: &mut [Step], buffers: &mut [Vec<f32>], nonzero: &mut [u32]) {
    #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
    // SAFETY: `CompiledNetwork::lower` refuses an instruction set this CPU does not run, and
    // `isa` cannot change afterwards.
    unsafe {
        match isa {
            Isa::Avx512 => return x86::run_avx512(steps, buffers, nonzero),
            Isa::Avx2Fma => return x86::run_avx2_fma(steps, buffers, nonzero),
            Isa::Sse42 => return x86::run_sse42(steps, buffers, nonzero),
            Isa::Ssse3 => return x86::run_ssse3(steps, buffers, nonzero),
            Isa::Sse2 => return x86::run_sse2(steps, buffers, nonzero),
            Isa::Portable => {}
        }
    }
    let _ = isa;
    run_portable(steps, buffers, nonzero);
}

/// The portable path: no target features, product and sum rounded separately.
#[inline(never)]
fn run_portable(steps: &mut [Step], buffers: &mut [Vec<f32>], nonzero: &mut [u32]) {
    plan::run::<kernels::Generic<kernels::Separate>>(steps, buffers, nonzero);
}

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
mod x86 {
    use super::kernels::{Avx512Kernels, AvxKernels, SseKernels};
    use super::plan::{Step, run};

    /// `run` with `kernels`, compiled for the target features `features` (one function each:
    /// `#[target_feature]` takes no generics).
    macro_rules! run_compiled_for {
        ($($name:ident: $features:literal, $kernels:ty;)*) => {$(
            #[target_feature(enable = $features)]
            pub(super) fn $name(steps: &mut [Step], buffers: &mut [Vec<f32>], nonzero: &mut [u32]) {
                run::<$kernels>(steps, buffers, nonzero);
            }
        )*};
    }

    run_compiled_for! {
        run_avx512: "avx,avx2,fma,avx512f", Avx512Kernels;
        run_avx2_fma: "avx,avx2,fma", AvxKernels;
        run_sse42: "sse2,sse3,ssse3,sse4.1,sse4.2", SseKernels;
        run_ssse3: "sse2,sse3,ssse3", SseKernels;
        run_sse2: "sse2", SseKernels;
    }
}

#[cfg(test)]
mod tests;
