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
    let output = controller_command()
        .args(["--rate-hz", "0", "dry-run"])
        .output()
        .expect("run dribble-controller");
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("--rate-hz must be in (0, 10000]"));
}
