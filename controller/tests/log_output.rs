//! The robot binary's log on standard error: logfmt by default, JSON with `--log-format json`,
//! filtered by `RUST_LOG`, and a clear refusal of a filter it cannot read.

mod support;

use std::process::Output;

use support::controller_command;

/// A short dry run (which logs the `realtime` event at info) with these settings.
fn dry_run(log_format: Option<&str>, rust_log: Option<&str>) -> Output {
    let mut command = controller_command();
    if let Some(format) = log_format {
        command.args(["--log-format", format]);
    }
    match rust_log {
        Some(filter) => command.env("RUST_LOG", filter),
        None => command.env_remove("RUST_LOG"),
    };
    command
        .args(["dry-run", "--seconds", "0.05", "--no-lock-memory"])
        .output()
        .expect("run dribble-controller")
}

#[test]
fn events_are_logfmt_lines_by_default() {
    let output = dry_run(None, None);
    assert!(output.status.success(), "{output:?}");
    let stderr = String::from_utf8_lossy(&output.stderr);
    let line = stderr
        .lines()
        .find(|line| line.contains("event=realtime"))
        .unwrap_or_else(|| panic!("no realtime event in {stderr}"));
    assert!(line.starts_with("ts=20"), "{line}");
    assert!(
        line.contains(" level=info event=realtime in_force="),
        "{line}"
    );
}

#[test]
fn json_lines_carry_the_same_fields() {
    let output = dry_run(Some("json"), None);
    assert!(output.status.success(), "{output:?}");
    let stderr = String::from_utf8_lossy(&output.stderr);
    let events: Vec<serde_json::Value> = stderr
        .lines()
        .map(|line| serde_json::from_str(line).unwrap_or_else(|e| panic!("{e}: {line}")))
        .collect();
    let realtime = events
        .iter()
        .find(|event| event["event"] == "realtime")
        .unwrap_or_else(|| panic!("no realtime event in {stderr}"));
    assert_eq!(realtime["level"], "INFO", "{realtime}");
    assert!(realtime["in_force"].is_string(), "{realtime}");
    assert!(realtime["timestamp"].is_string(), "{realtime}");
}

#[test]
fn rust_log_filters_by_level() {
    let output = dry_run(None, Some("warn"));
    assert!(output.status.success(), "{output:?}");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!stderr.contains("event=realtime"), "{stderr}");
}

#[test]
fn a_filter_or_format_it_cannot_read_is_refused_with_the_reason() {
    let output = dry_run(None, Some("info,[[nonsense"));
    assert_eq!(output.status.code(), Some(1), "{output:?}");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("RUST_LOG=\"info,[[nonsense\""), "{stderr}");

    let output = dry_run(Some("yaml"), None);
    assert!(!output.status.success(), "{output:?}");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("unknown log format \"yaml\""), "{stderr}");
}
