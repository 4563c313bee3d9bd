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
