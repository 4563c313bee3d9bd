//! The robot binary's dry run: the real loop on the real clock with the test pattern.

use std::process::Command;

/// The controller binary; under `cross/test` it runs on the same emulated CPU as the tests
/// (`DRIBBLE_TEST_RUNNER`, e.g. `qemu-i386 -cpu n270 ...`).
fn controller() -> Command {
    let binary = env!("CARGO_BIN_EXE_dribble-controller");
    let runner = std::env::var("DRIBBLE_TEST_RUNNER").unwrap_or_default();
    let mut parts = runner.split_whitespace();
    match parts.next() {
        Some(emulator) => {
            let mut command = Command::new(emulator);
            command.args(parts).arg(binary);
            command
        }
        None => Command::new(binary),
    }
}

#[test]
fn dry_run_computes_commands_and_prints_its_statistics() {
    let output = controller()
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
    let output = controller()
        .args(["--rate-hz", "0", "dry-run"])
        .output()
        .expect("run dribble-controller");
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("--rate-hz must be in (0, 10000]"));
}
