//! The controller process under soak: found, started on a copy of the policy, waited for,
//! sampled (`/proc/PID`: resident memory, open files), stopped; what it says as it stops.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, bail, ensure};
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_controller::realtime::{self, RealtimeRequest};
use dribble_controller::transport::ipc::Iceoryx2SimulatorPorts;

use crate::commands::soak::SoakArgs;

/// Resident memory and open files of process `pid`, from /proc.
pub(crate) fn sample_process(pid: u32) -> anyhow::Result<(u64, u64)> {
    let status = fs::read_to_string(format!("/proc/{pid}/status"))
        .with_context(|| format!("the controller (pid {pid}) is gone"))?;
    let rss_kib = status
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|value| value.split_whitespace().next())
        .and_then(|kib| kib.parse().ok())
        .context("no VmRSS in /proc/PID/status")?;
    let open_files = fs::read_dir(format!("/proc/{pid}/fd"))
        .context("cannot list the controller's open files")?
        .count() as u64;
    Ok((rss_kib, open_files))
}

/// The controller process, stopped (SIGTERM, then SIGKILL) when dropped.
pub(crate) struct ControllerProcess(pub(crate) Child);

impl Drop for ControllerProcess {
    fn drop(&mut self) {
        if let Ok(pid) = i32::try_from(self.0.id()) {
            // SAFETY: kill takes a pid and a signal number only.
            #[allow(unsafe_code)]
            unsafe {
                libc::kill(pid, libc::SIGTERM);
            }
        }
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Copies the policy's directory to `to`; returns the copy's manifest and first network.
pub(crate) fn copy_policy(manifest: &Path, to: &Path) -> anyhow::Result<(PathBuf, PathBuf)> {
    let from = manifest.parent().context("the policy has no directory")?;
    fs::create_dir_all(to)?;
    for entry in fs::read_dir(from)? {
        let path = entry?.path();
        if path.is_file() {
            fs::copy(&path, to.join(path.file_name().context("a file name")?))?;
        }
    }
    let copy = to.join(manifest.file_name().context("a manifest name")?);
    let parsed = PolicyManifest::load(&copy)?;
    let network = parsed
        .network_paths()
        .next()
        .context("the policy names no network")?;
    Ok((copy, network))
}

pub(crate) fn start_controller(
    args: &SoakArgs,
    policy: &Path,
    domain: &str,
    log: &Path,
) -> anyhow::Result<Child> {
    let binary = crate::controller_session::controller_binary(args.controller.as_deref())?;
    ensure!(
        binary.is_file(),
        "no controller binary at {}",
        binary.display()
    );
    let log_file = fs::File::create(log)
        .with_context(|| format!("cannot write the controller log {}", log.display()))?;
    let mut command = Command::new(&binary);
    command
        .args(["run", "--clock", "monotonic", "--domain", domain])
        .arg("--policy")
        .arg(policy)
        .stdin(Stdio::null())
        .stdout(log_file.try_clone()?)
        .stderr(log_file);
    if args.priority > 0 {
        command.args(["--fifo-priority", &args.priority.to_string()]);
    }
    if let Some(isa) = args.isa {
        command.args(["--isa", isa.name()]);
    }
    command
        .spawn()
        .with_context(|| format!("cannot start {}", binary.display()))
}

/// Waits (30 s at most) until the controller has opened its ports.
pub(crate) fn wait_for_connection(
    ports: &Iceoryx2SimulatorPorts,
    controller: &mut ControllerProcess,
    log: &Path,
) -> anyhow::Result<()> {
    let connect_deadline = Instant::now() + Duration::from_secs(30);
    while !ports.controller_connected() {
        if let Some(status) = controller.0.try_wait()? {
            bail!(
                "the controller exited ({status}) before connecting; its log: {}",
                log.display()
            );
        }
        ensure!(
            Instant::now() < connect_deadline,
            "the controller did not connect in 30 s; its log: {}",
            log.display()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(())
}

/// This process (cameras and motion side) one priority below the controller, memory locked;
/// a refusal is a warning.
pub(crate) fn apply_realtime(controller_priority: u8) {
    let report = realtime::apply(RealtimeRequest {
        lock_memory: true,
        fifo_priority: (controller_priority > 1).then(|| controller_priority - 1),
        cpu: None,
    });
    println!(
        "soak: this process (cameras and motion side): {}",
        report.in_force_text()
    );
    for refusal in &report.refused {
        tracing::warn!(event = "realtime_refused", setting = %refusal, action = "the soak runs on without it");
    }
}
