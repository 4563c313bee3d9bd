//! ONNX files: any bytes as a CNN policy's network (truncated, bit-flipped, wrong operators,
//! huge declared shapes: the seed corpus holds the fixtures, libFuzzer mutates them). The
//! contract: loading returns a typed error naming the file, or a policy whose step runs;
//! a panic inside tract while loading is contained (`OnnxPolicy::load_with` catches it), so
//! the panic hook is silenced here and only an uncontained panic or a crash is a finding.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
use dribble_controller::{BottomThumbnail, Policy, PolicyInput, TopThumbnail};
use libfuzzer_sys::fuzz_target;

const MANIFEST: &str = include_str!("../../../models/fixtures/cnn/policy.toml");

fn model_directory() -> &'static PathBuf {
    static DIRECTORY: OnceLock<PathBuf> = OnceLock::new();
    DIRECTORY.get_or_init(|| {
        let directory = PathBuf::from(format!("/dev/shm/dribble-fuzz-onnx-{}", std::process::id()));
        std::fs::create_dir_all(&directory).expect("model directory");
        std::fs::write(directory.join("policy.toml"), MANIFEST).expect("manifest");
        directory
    })
}

fuzz_target!(
    init: {
        std::panic::set_hook(Box::new(|_| {}));
    },
    |data: &[u8]| {
        let directory = model_directory();
        std::fs::write(directory.join("policy.onnx"), data).expect("network file");
        let manifest = directory.join("policy.toml");
        for engine in [Engine::Compiled, Engine::Tract] {
            let options = EngineOptions { engine, isa: None };
            match OnnxPolicy::load_with(&manifest, options) {
                Ok((mut policy, _)) => {
                    let (top, bottom) = (TopThumbnail::black(), BottomThumbnail::black());
                    let _ = policy.step(PolicyInput::at_rest(&top, &bottom));
                }
                Err(error) => assert!(error.to_string().contains("dribble-fuzz-onnx"), "{error}"),
            }
        }
    }
);
