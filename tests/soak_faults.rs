//! The soak's fault injection, end to end: the controller process at the robot's rates over
//! iceoryx2 meets a 1 s camera pause, a publisher restart, a second controller in its
//! domain and its policy file replaced on disk, and answers each as documented (the
//! summary's per-fault verdicts, checked here), with no command lost and flat memory.

mod support;

use std::path::PathBuf;
use std::process::{Command, Output};

/// `dribble soak ARGS` on the fixture policy, into a fresh directory (returned: removed first).
fn soak(name: &str, args: &[&str]) -> (Output, PathBuf) {
    let out = std::env::temp_dir().join(format!("dribble-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let output = Command::new(env!("CARGO_BIN_EXE_dribble"))
        .arg("soak")
        .args(args)
        .arg("--policy")
        .arg(support::fixture_manifest("cnn"))
        .arg("--out")
        .arg(&out)
        .output()
        .expect("run dribble soak");
    (output, out)
}

#[test]
fn each_fault_gets_its_documented_answer() {
    // Deadlines are for the real soak (scripts/soak); test machines are shared.
    let (output, out) = soak(
        "soak-faults",
        &[
            "--faults",
            "--minutes",
            "0.6",
            "--warm-up-s",
            "5",
            "--max-missed-share",
            "0.05",
            "--priority",
            "0",
        ],
    );
    let said = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(output.status.success(), "{said}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("soak.json")).expect("summary"))
            .expect("json");
    let faults = summary["faults"].as_array().expect("faults");
    let names: Vec<&str> = faults.iter().filter_map(|f| f["fault"].as_str()).collect();
    assert_eq!(
        names,
        [
            "camera pause (1 s)",
            "publisher restart",
            "second controller in the domain",
            "policy file replaced on disk"
        ]
    );
    for fault in faults {
        println!("{}: {}", fault["fault"], fault["detail"]);
        assert_eq!(fault["passed"], true, "{fault}");
    }
    assert_eq!(summary["lost"], 0, "{said}");
    // The verdict is written with the figures (the book's soak page reads it).
    assert_eq!(summary["failures"], serde_json::json!([]), "{said}");
    assert!(summary["computed"].as_u64() > Some(500), "{said}");
    let log = std::fs::read_to_string(out.join("controller.log")).expect("controller log");
    for event in [
        "event=cameras_silent",
        "event=cameras_back",
        "event=camera_resynced",
        "event=policy_file_changed",
    ] {
        assert!(log.contains(event), "{event}: {log}");
    }
    // The policy the repository ships was never touched: the controller ran a copy.
    assert!(out.join("policy/policy.onnx").is_file());
    std::fs::remove_dir_all(out).expect("clean up");
}

#[test]
fn an_unknown_instruction_set_is_refused_before_anything_starts() {
    let (output, out) = soak("soak-isa", &["--minutes", "0.1", "--isa", "sse9"]);
    let said = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{said}");
    assert!(
        said.contains("unknown instruction set") && said.contains("ssse3"),
        "{said}"
    );
    assert!(!out.exists(), "nothing is written for a refused run");
}
