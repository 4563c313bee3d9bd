//! The robot binary's dry run: the real loop on the real clock with the test pattern.

mod support;

use support::controller_command;

#[test]
fn dry_run_computes_commands_and_prints_its_statistics() {
    let output = controller_command()
        .args(["dry-run", "--seconds", "0.5", "--drop-bottom-every", "3"])
        .output()
        .expect("run dribble-controller");
    assert!(output.status.success(), "{output:?}");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let field = |name: &str| -> u64 {
        let at = stdout
            .find(name)
            .unwrap_or_else(|| panic!("no {name:?} in {stdout}"));
        stdout[..at]
            .split_whitespace()
            .last()
            .and_then(|n| n.trim_end_matches(':').parse().ok())
            .unwrap_or_else(|| panic!("no number before {name:?} in {stdout}"))
    };
    assert!(field(" new,") > 0, "{stdout}");
    assert!(field(" repeated,") > 0, "{stdout}");
    assert!(stdout.contains("tick time: "), "{stdout}");
}

#[test]
fn a_nonsense_rate_is_refused() {
    for rate in ["0", "1e-30", "0.5", "-3", "NaN", "inf", "20000"] {
        let output = controller_command()
            .arg(format!("--rate-hz={rate}"))
            .args(["dry-run", "--seconds", "0.1"])
            .output()
            .expect("run dribble-controller");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{rate}: {stderr}");
        assert!(!stderr.contains("panicked"), "{rate}: {stderr}");
        assert!(
            stderr.contains("--rate-hz must be in [1, 10000]"),
            "{rate}: {stderr}"
        );
    }
}

#[test]
fn forward_whole_tick_computes_a_command_from_each_new_pair_of_frames() {
    let policy = support::fixture("cnn").join("policy.toml");
    let policy = policy.to_str().expect("the checkout's path is UTF-8");
    let run = |extra: &[&str]| {
        let output = controller_command()
            .args(["forward", "--no-peak", "--steps", "3", "--policy", policy])
            .args(extra)
            .output()
            .expect("run dribble-controller");
        assert!(output.status.success(), "{output:?}");
        String::from_utf8_lossy(&output.stdout).into_owned()
    };
    let ticks = run(&["--whole-tick"]);
    assert!(ticks.contains("3 computing tick(s)"), "{ticks}");
    // The third tick computed from the third pair of frames, as a new command.
    assert!(
        ticks.contains("top_sequence: 3, bottom_sequence: 3"),
        "{ticks}"
    );
    assert!(
        ticks.contains("time per computing tick: 3 ticks"),
        "{ticks}"
    );
    // The same thumbnails, so the same numbers as the bare forward pass (inside [-1, 1]).
    let passes = run(&[]);
    let number = |text: &str, name: &str| -> String {
        let at = text.find(&format!("{name}: ")).expect(name) + name.len() + 2;
        text[at..]
            .split([',', ' ', '}'])
            .next()
            .unwrap_or_default()
            .to_owned()
    };
    for name in ["forward", "left", "turn"] {
        assert_eq!(
            number(&ticks, name),
            number(&passes, name),
            "{ticks}\n{passes}"
        );
    }
}

#[test]
fn a_reader_that_has_gone_ends_a_report_quietly() {
    // `dry-run ... | head -0`: the pipe's reader is closed before the first line is written.
    // Rust ignores SIGPIPE, so `println!` panicked here; the reporting commands now end
    // quietly, as a C tool would.
    let (reader, writer) = std::io::pipe().expect("a pipe");
    drop(reader);
    let output = controller_command()
        .args(["dry-run", "--seconds", "0.1"])
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .expect("run dribble-controller");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(output.status.success(), "{output:?}");
}

#[test]
fn forward_layers_lists_the_plan_and_a_single_layer_runs_alone() {
    let policy = support::fixture("cnn").join("policy.toml");
    let policy = policy.to_str().expect("the checkout's path is UTF-8");
    let output = controller_command()
        .args(["--isa", "ssse3", "forward", "--steps", "2", "--layers"])
        .args(["--policy", policy])
        .output()
        .expect("run dribble-controller");
    assert!(output.status.success(), "{output:?}");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let json = stdout
        .lines()
        .find_map(|line| line.strip_prefix("layers "))
        .unwrap_or_else(|| panic!("no layers line in {stdout}"));
    let table: serde_json::Value = serde_json::from_str(json).expect("layers JSON");
    let steps = table["steps"].as_array().expect("steps");
    // The fixture CNN: two convolutions a camera and two dense layers, with the padding,
    // layout and copy steps between them. The dense layers' multiply-adds are their weights
    // (a convolution's count depends on whether this build runs it by Winograd).
    let named = |prefix: &str| -> Vec<u64> {
        steps
            .iter()
            .filter(|step| step["name"].as_str().is_some_and(|n| n.starts_with(prefix)))
            .map(|step| step["multiply_adds"].as_u64().expect("count"))
            .collect()
    };
    let convolutions = named("conv");
    assert_eq!(convolutions.len(), 4, "{json}");
    assert!(convolutions.iter().all(|&n| n > 0), "{json}");
    assert_eq!(named("dense"), [2560 * 128, 128 * 3], "{json}");
    let single = controller_command()
        .args([
            "forward", "--steps", "3", "--layer", "1", "--policy", policy,
        ])
        .output()
        .expect("run dribble-controller");
    assert!(single.status.success(), "{single:?}");
    assert!(
        String::from_utf8_lossy(&single.stdout).contains("3 run(s) of layer 1 of"),
        "{single:?}"
    );
    let past = controller_command()
        .args(["forward", "--layer", "999", "--policy", policy])
        .output()
        .expect("run dribble-controller");
    assert_eq!(past.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&past.stderr).contains("--layer 999: the plan has"),
        "{past:?}"
    );
}
