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

/// `VmLck` of this process, KiB, from `/proc/self/status`.
fn locked_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
    status
        .lines()
        .find_map(|line| line.strip_prefix("VmLck:"))
        .and_then(|value| value.split_whitespace().next())
        .and_then(|kib| kib.parse().ok())
        .expect("VmLck in /proc/self/status")
}

/// The calling thread's scheduling policy and priority, as the kernel has them.
fn scheduler() -> (i32, i32) {
    // SAFETY: both calls take the calling thread (0) and a parameter block they fill.
    #[allow(unsafe_code)]
    unsafe {
        let mut parameter: libc::sched_param = std::mem::zeroed();
        let policy = libc::sched_getscheduler(0);
        assert_eq!(libc::sched_getparam(0, &mut parameter), 0, "sched_getparam");
        (policy, parameter.sched_priority)
    }
}

/// The CPUs the calling thread may run on, as the kernel has them.
fn affinity() -> Vec<usize> {
    // SAFETY: the set is a plain bit mask the call fills; CPU_ISSET reads within its size.
    #[allow(unsafe_code)]
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        assert_eq!(
            libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set),
            0,
            "sched_getaffinity"
        );
        (0..libc::CPU_SETSIZE as usize)
            .filter(|&cpu| libc::CPU_ISSET(cpu, &set))
            .collect()
    }
}

#[test]
fn what_the_report_calls_in_force_is_what_the_kernel_reads_back() {
    use dribble_controller::realtime::{self, RealtimeRequest, Setting};
    // A thread of its own: the priority and the pinning are the calling thread's and end
    // with it; the memory lock is the process's and is undone at the end.
    let (report, locked, sched, cpus, unlocked) = std::thread::spawn(|| {
        let report = realtime::apply(RealtimeRequest {
            lock_memory: true,
            fifo_priority: Some(10),
            cpu: Some(0),
        });
        let read = (locked_kib(), scheduler(), affinity());
        // SAFETY: munlockall takes no arguments.
        #[allow(unsafe_code)]
        let unlocked = unsafe { libc::munlockall() } == 0;
        (report, read.0, read.1, read.2, unlocked)
    })
    .join()
    .expect("the settings thread");
    assert!(unlocked, "munlockall");
    println!(
        "in force: {}; refused: {:?}; VmLck {locked} KiB, scheduler {sched:?}, CPUs {cpus:?}",
        report.in_force_text(),
        report.refused
    );
    let in_force = |setting| report.in_force.contains(&setting);
    // Each setting is reported in force exactly when the kernel has it.
    assert_eq!(
        in_force(Setting::LockMemory),
        locked > 0,
        "VmLck {locked} KiB"
    );
    assert_eq!(
        in_force(Setting::Fifo(10)),
        sched == (libc::SCHED_FIFO, 10),
        "{sched:?}"
    );
    assert_eq!(in_force(Setting::Cpu(0)), cpus == [0], "{cpus:?}");
    assert_eq!(report.in_force.len() + report.refused.len(), 3);
    // Pinning needs no privilege; as root (here and in CI) nothing may be refused.
    assert!(in_force(Setting::Cpu(0)), "{:?}", report.refused);
    // SAFETY: geteuid takes no arguments.
    #[allow(unsafe_code)]
    if unsafe { libc::geteuid() } == 0 {
        assert!(report.refused.is_empty(), "{:?}", report.refused);
    }
}
