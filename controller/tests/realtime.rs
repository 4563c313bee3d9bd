//! The real-time settings as the robot process applies them: what takes effect is logged,
//! what the kernel refuses is a warning (the controller runs on), and `--require-realtime`
//! turns a refusal into a refusal to start.

mod support;

use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Command, Output};

use support::controller_command;

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn settings_that_take_effect_are_logged_and_an_impossible_one_is_refused_by_name() {
    let output = controller_command()
        .args(["dry-run", "--seconds", "0.3", "--cpu", "0"])
        .output()
        .expect("run dribble-controller");
    let log = stderr(&output);
    assert!(output.status.success(), "{log}");
    let in_force = log
        .lines()
        .find(|line| line.contains("event=realtime "))
        .unwrap_or_else(|| panic!("no realtime line: {log}"));
    // Pinning to CPU 0 needs no privilege; memory locking may be refused (then it says so).
    assert!(in_force.contains("pinned to CPU 0"), "{in_force}");
    assert!(
        in_force.contains("memory locked")
            || log.contains("event=realtime_refused setting=\"memory locked (mlockall)\""),
        "{log}"
    );

    let output = controller_command()
        .args([
            "dry-run",
            "--seconds",
            "0.3",
            "--no-lock-memory",
            "--cpu",
            "100000",
        ])
        .output()
        .expect("run dribble-controller");
    let log = stderr(&output);
    assert!(output.status.success(), "runs on: {log}");
    assert!(
        log.contains("level=warn event=realtime_refused setting=\"pinned to CPU 100000\""),
        "{log}"
    );
    assert!(log.contains("no CPU 100000 on this machine"), "{log}");
    assert!(log.contains("in_force=none"), "{log}");
}

#[test]
fn a_priority_outside_sched_fifo_is_a_usage_error() {
    for priority in ["0", "100", "-1"] {
        let output = controller_command()
            .arg("dry-run")
            .arg(format!("--fifo-priority={priority}"))
            .output()
            .expect("run dribble-controller");
        assert_eq!(
            output.status.code(),
            Some(2),
            "{priority}: {}",
            stderr(&output)
        );
    }
}

/// The controller binary where an unprivileged user can run it (the build directory may sit
/// in root's home).
fn binary_for_anyone() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dribble-realtime-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).expect("chmod");
    let binary = dir.join("dribble-controller");
    std::fs::copy(env!("CARGO_BIN_EXE_dribble-controller"), &binary).expect("copy");
    std::fs::set_permissions(&binary, std::fs::Permissions::from_mode(0o755)).expect("chmod");
    binary
}

/// The dry run as a process without real-time privileges: no locked memory and no real-time
/// priority allowed by its limits, and, when the tests run as root, as user `nobody` (so no
/// capability overrides the limits).
fn unprivileged_dry_run(binary: &PathBuf, extra: &[&str]) -> Output {
    let runner = std::env::var("DRIBBLE_TEST_RUNNER").unwrap_or_default();
    let mut parts = runner.split_whitespace();
    let mut command = match parts.next() {
        Some(emulator) => {
            let mut command = Command::new(emulator);
            command.args(parts).arg(binary);
            command
        }
        None => Command::new(binary),
    };
    command
        .args(["dry-run", "--seconds", "0.3", "--fifo-priority", "40"])
        .args(extra)
        .current_dir(std::env::temp_dir());
    // SAFETY: between fork and exec only async-signal-safe calls are made (setrlimit,
    // geteuid, setgroups, setgid, setuid), on values prepared before the fork.
    #[allow(unsafe_code)]
    unsafe {
        command.pre_exec(|| {
            let none = libc::rlimit {
                rlim_cur: 0,
                rlim_max: 0,
            };
            for resource in [libc::RLIMIT_MEMLOCK, libc::RLIMIT_RTPRIO] {
                if libc::setrlimit(resource, &none) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            if libc::geteuid() == 0
                && (libc::setgroups(0, std::ptr::null()) != 0
                    || libc::setgid(65534) != 0
                    || libc::setuid(65534) != 0)
            {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    command.output().expect("run dribble-controller")
}

#[test]
fn without_privileges_each_refusal_is_a_warning_and_require_realtime_refuses_to_start() {
    let binary = binary_for_anyone();
    let output = unprivileged_dry_run(&binary, &[]);
    let log = stderr(&output);
    assert!(output.status.success(), "runs on: {log}");
    for setting in ["memory locked (mlockall)", "SCHED_FIFO priority 40"] {
        assert!(
            log.contains(&format!(
                "level=warn event=realtime_refused setting=\"{setting}\""
            )),
            "{setting}: {log}"
        );
    }
    assert!(log.contains("running on without it"), "{log}");
    assert!(log.contains("in_force=none"), "{log}");
    assert!(String::from_utf8_lossy(&output.stdout).contains("tick time: "));

    let output = unprivileged_dry_run(&binary, &["--require-realtime"]);
    let log = stderr(&output);
    assert_eq!(output.status.code(), Some(1), "{log}");
    assert!(log.contains("level=error event=realtime_refused"), "{log}");
    assert!(log.contains("--require-realtime: "), "{log}");
    assert!(
        !String::from_utf8_lossy(&output.stdout).contains("tick time: "),
        "never ran"
    );
    std::fs::remove_dir_all(binary.parent().expect("dir")).expect("clean up");
}
