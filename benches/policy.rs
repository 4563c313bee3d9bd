//! Policy steps of the committed fixture policies (the paper's architectures with seeded
//! weights), per kind, on the compiled engine (this CPU's widest instruction set, AVX2+FMA
//! where that is wider still, the Nao V6's SSE4.2 and the V5's SSSE3) and on tract. Whole ticks with a real policy are in
//! `benches/tick.rs`.
//!
//! Each compiled engine's step also prints its floor: the network's multiply-adds at this
//! core's arithmetic peak for the set, measured when the run starts
//! (`policy::engine::peak`), so a figure reads as a fraction of what the machine allows.
//!
//! tract chooses its kernels once per process from `TRACT_CPU_ISA`, so its SSE-only figures
//! come from a second run of this benchmark that it starts itself with
//! `TRACT_CPU_ISA=-avx,-avx2,-fma,-f16c,-avx512f` (group "tract SSE only"); both runs'
//! figures print together.

use std::hint::black_box;
use std::process::Command;

use criterion::Criterion;
use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::engine::peak::{
    int8_multiply_adds_per_second, multiply_adds_per_second,
};
use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::thumbnail::downscale;
use dribble_controller::{
    BottomFrame, BottomThumbnail, Policy, PolicyInput, Timestamp, TopFrame, TopThumbnail,
};

mod support;

/// Set in the second run, which measures tract with SSE only.
const SSE_ONLY_RUN: &str = "DRIBBLE_BENCH_TRACT_SSE_ONLY";
const TRACT_SSE_ONLY: &str = "-avx,-avx2,-fma,-f16c,-avx512f";

fn load(kind: &str, engine: Engine, isa: Option<Isa>) -> OnnxPolicy {
    let manifest = support::fixture_manifest(kind);
    let policy = OnnxPolicy::load_with(&manifest, EngineOptions { engine, isa })
        .unwrap_or_else(|error| panic!("{error}"))
        .0;
    if engine == Engine::Compiled {
        assert!(policy.engine().compiled.is_some(), "{}", policy.engine());
    }
    policy
}

/// The engines measured in this run: (label, engine, instruction set).
fn engines() -> Vec<(String, Engine, Option<Isa>)> {
    if std::env::var_os(SSE_ONLY_RUN).is_some() {
        return vec![("tract SSE only".into(), Engine::Tract, None)];
    }
    let mut engines = vec![(
        format!("engine {}", Isa::detect()),
        Engine::Compiled,
        Some(Isa::detect()),
    )];
    for isa in [Isa::Avx2Fma, Isa::Sse42, Isa::Ssse3] {
        if isa.is_available() && isa != Isa::detect() {
            engines.push((format!("engine {isa}"), Engine::Compiled, Some(isa)));
        }
    }
    engines.push(("tract".into(), Engine::Tract, None));
    engines
}

fn policies(c: &mut Criterion) {
    let pattern = TestPattern::default();
    let (mut top_frame, mut bottom_frame) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    pattern.paint(&mut top_frame, 0, Timestamp::ZERO);
    pattern.paint(&mut bottom_frame, 0, Timestamp::ZERO);
    let (mut top, mut bottom) = (
        Box::new(TopThumbnail::black()),
        Box::new(BottomThumbnail::black()),
    );
    downscale(&top_frame, &mut top);
    downscale(&bottom_frame, &mut bottom);

    for (label, engine, isa) in engines() {
        let mut group = c.benchmark_group(format!("policy step/{label}"));
        let peak = isa.and_then(multiply_adds_per_second);
        let int8_peak = isa.and_then(int8_multiply_adds_per_second);
        for (name, kind) in [
            ("CNN", "cnn"),
            ("CNN int8", "cnn-int8"),
            ("H-CNN", "hcnn"),
            ("R-CNN", "rcnn"),
        ] {
            let mut policy = load(kind, engine, isa);
            // The floor no kernel goes below: this step's multiply-adds at this core's
            // measured peak for the set (compare with criterion's figure below it).
            // An int8 plan's floor is at the int8 peak.
            let peak = if policy.engine().int8 {
                int8_peak
            } else {
                peak
            };
            if let (Some(peak), Some(multiply_adds)) = (peak, policy.engine().multiply_adds) {
                println!(
                    "policy step/{label}/{name}: {:.2} M multiply-adds, at least {:.1} µs at \
                     this core's measured peak of {:.1} G a second",
                    multiply_adds as f64 / 1e6,
                    multiply_adds as f64 / peak * 1e6,
                    peak / 1e9
                );
            }
            group.bench_function(name, |b| {
                b.iter(|| {
                    let input = PolicyInput::at_rest(black_box(&top), black_box(&bottom));
                    black_box(policy.step(input).expect("step"))
                })
            });
        }
        group.finish();
    }
}

fn main() {
    let mut criterion = Criterion::default().configure_from_args();
    policies(&mut criterion);
    criterion.final_summary();
    if std::env::var_os(SSE_ONLY_RUN).is_none() {
        // tract with SSE only, in a process of its own (it reads its ISA once), with the same
        // arguments (`--bench` or test mode under `cargo test`, options with their values,
        // the filter).
        let flags: Vec<String> = std::env::args().skip(1).collect();
        let status = std::env::current_exe().and_then(|exe| {
            Command::new(exe)
                .args(&flags)
                .env(SSE_ONLY_RUN, "1")
                .env("TRACT_CPU_ISA", TRACT_SSE_ONLY)
                .status()
        });
        match status {
            Ok(status) if status.success() => {}
            other => panic!("the tract SSE-only run failed: {other:?}"),
        }
    }
}
