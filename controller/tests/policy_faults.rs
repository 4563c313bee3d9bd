//! Bad models fail at load with a message that says what was expected and found; a model
//! that answers NaN at run time gives a counted stop. Nothing panics.

mod support;

use std::fs;
use std::path::Path;

use dribble_controller::policy::{OnnxPolicy, PolicyLoadError};
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::{
    BottomFrame, CameraInput, ControlLoop, LoopConfig, ManualClock, Timestamp, TopFrame,
};
use support::{fixture, scratch_copy};

fn load_error(manifest: &Path) -> String {
    match OnnxPolicy::load(manifest) {
        Ok(_) => panic!("{} loaded, but it is broken", manifest.display()),
        Err(error) => error.to_string(),
    }
}

fn edit_manifest(directory: &Path, from: &str, to: &str) {
    let path = directory.join("policy.toml");
    let text = fs::read_to_string(&path).expect("manifest");
    assert!(text.contains(from), "{from:?} not in the manifest");
    fs::write(&path, text.replacen(from, to, 1)).expect("write manifest");
}

#[test]
fn a_missing_manifest_is_named() {
    let path = Path::new("/nonexistent/policy.toml");
    let error = OnnxPolicy::load(path).expect_err("missing");
    assert!(matches!(error, PolicyLoadError::Io { .. }));
    assert!(
        error
            .to_string()
            .starts_with("cannot read /nonexistent/policy.toml"),
        "{error}"
    );
}

#[test]
fn a_missing_network_file_is_named() {
    let directory = scratch_copy("cnn", "missing-onnx");
    fs::remove_file(directory.join("policy.onnx")).expect("remove");
    let error = load_error(&directory.join("policy.toml"));
    assert!(
        error.contains("cannot read") && error.contains("policy.onnx"),
        "{error}"
    );
}

#[test]
fn a_truncated_onnx_file_is_refused() {
    let directory = scratch_copy("cnn", "truncated");
    let onnx = directory.join("policy.onnx");
    let bytes = fs::read(&onnx).expect("read");
    fs::write(&onnx, &bytes[..bytes.len() / 3]).expect("truncate");
    let error = load_error(&directory.join("policy.toml"));
    assert!(
        error.contains("policy.onnx is not a readable ONNX model"),
        "{error}"
    );
}

#[test]
fn random_bytes_are_refused() {
    let directory = scratch_copy("cnn", "random");
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let noise: Vec<u8> = (0..50_000)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state as u8
        })
        .collect();
    fs::write(directory.join("policy.onnx"), noise).expect("write");
    let error = load_error(&directory.join("policy.toml"));
    assert!(error.contains("policy.onnx"), "{error}");
}

#[test]
fn an_input_name_the_file_lacks_is_reported_with_both_lists() {
    let directory = scratch_copy("cnn", "input-name");
    edit_manifest(&directory, "name = \"top\"", "name = \"camera_top\"");
    let error = load_error(&directory.join("policy.toml"));
    assert!(
        error.contains(r#"inputs must be ["bottom", "camera_top"], found ["bottom", "top"]"#),
        "{error}"
    );
}

#[test]
fn a_wrong_shape_in_the_manifest_is_refused() {
    let directory = scratch_copy("cnn", "shape");
    edit_manifest(&directory, "[1, 1, 60, 80]", "[1, 1, 120, 160]");
    let error = load_error(&directory.join("policy.toml"));
    assert!(
        error.contains("inputs.bottom (\"bottom\") has shape [1, 1, 120, 160]"),
        "{error}"
    );
}

#[test]
fn an_opset_other_than_the_files_is_refused() {
    let directory = scratch_copy("cnn", "opset");
    edit_manifest(&directory, "opset = 17", "opset = 13");
    let error = load_error(&directory.join("policy.toml"));
    assert!(
        error.contains("ONNX operator set must be 13 (from the manifest), found 17"),
        "{error}"
    );
}

#[test]
fn a_cnn_file_under_an_rcnn_manifest_is_refused() {
    let directory = scratch_copy("rcnn", "kind");
    fs::copy(
        fixture("cnn").join("policy.onnx"),
        directory.join("policy.onnx"),
    )
    .expect("copy");
    let error = load_error(&directory.join("policy.toml"));
    assert!(
        error.contains(
            r#"inputs must be ["bottom", "c_in", "h_in", "top"], found ["bottom", "top"]"#
        ),
        "{error}"
    );
}

#[test]
fn a_network_answering_nan_gives_a_counted_stop() {
    let (policy, _) =
        OnnxPolicy::load(&fixture("nan").join("policy.toml")).expect("the NaN model is valid");
    let clock = ManualClock::default();
    let mut control = ControlLoop::new(LoopConfig::default(), policy, clock.clone());
    let pattern = TestPattern::default();
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    for sequence in 0..3 {
        clock.advance(std::time::Duration::from_millis(34));
        let now = Timestamp::from_nanos(sequence * 34_000_000);
        pattern.paint(&mut top, sequence, now);
        pattern.paint(&mut bottom, sequence, now);
        let command = control.tick(CameraInput {
            top: Some(&top),
            bottom: Some(&bottom),
        });
        assert!(command.is_new() && command.is_stop(), "{command:?}");
        assert!(command.speed.is_stop());
    }
    assert_eq!(control.counters().non_finite_outputs, 3);
    assert_eq!(control.counters().policy_failures, 0);
}
