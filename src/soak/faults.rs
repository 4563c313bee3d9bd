//! Faults `dribble soak --faults` injects while the controller runs, and what each must do
//! (DESIGN.md; the book, docs/src/design/transport.md):
//!
//! - **camera pause**: both streams stop for 1 s. The controller stops the robot on its first
//!   tick past the 100 ms silence limit ([`stop_within`]: the limit, one 10 ms tick and the
//!   2 ms tick budget after the pause began) and logs `cameras_silent`; when frames return
//!   it computes again and logs `cameras_back`.
//! - **publisher restart**: the camera publisher goes away for 0.5 s and comes back as a new
//!   process would, its sequence numbers from 0. The controller stops within the same bound,
//!   then follows the new numbers (`camera_resynced`) and computes again. The motion side
//!   reads on meanwhile, so a command lost during the restart is a gap in the sequence.
//! - **second controller**: another controller started in the same domain refuses to start
//!   ("another controller runs in it"); the running one is untouched (no command lost).
//! - **policy replaced**: the policy's network file is replaced on disk by a valid network of
//!   the same contract that answers one constant command ([`REPLACEMENT`]). Nothing changes
//!   until a restart: commands go on, no stop, none of them is the replacement's, and the
//!   controller logs `policy_file_changed`.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use dribble_controller::{LoopConfig, MotionCommand, SyncConfig, Timestamp};

pub use super::replacement_policy::{REPLACEMENT, replacement_network};
use time::OffsetDateTime;
use time::format_description::well_known::Rfc3339;

/// How long the cameras pause, and the publisher stays away.
const PAUSE: Duration = Duration::from_secs(1);
const RESTART_GAP: Duration = Duration::from_millis(500);
/// How long after a fault the controller has to show its reaction.
const SETTLE: Duration = Duration::from_secs(3);
/// How soon after the cameras fall silent a stop must arrive: the controller's silence
/// limit (3 camera periods, 100 ms, counted from the last frame, which came before the
/// fault), then its next tick (10 ms) and that tick's budget (2 ms).
pub fn stop_within() -> Duration {
    let config = LoopConfig::default();
    SyncConfig::default().silence_limit() + config.tick_period + config.budget
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    CameraPause,
    PublisherRestart,
    SecondController,
    PolicyReplaced,
}

impl FaultKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::CameraPause => "camera pause (1 s)",
            Self::PublisherRestart => "publisher restart",
            Self::SecondController => "second controller in the domain",
            Self::PolicyReplaced => "policy file replaced on disk",
        }
    }

    /// The controller log event each fault must produce.
    fn log_event(self) -> &'static str {
        match self {
            Self::CameraPause => "event=cameras_back",
            Self::PublisherRestart => "event=camera_resynced",
            Self::SecondController => "event=ready",
            Self::PolicyReplaced => "event=policy_file_changed",
        }
    }
}

/// One fault: when it starts, and what was seen after.
#[derive(Debug)]
struct Fault {
    kind: FaultKind,
    at: Timestamp,
    started: bool,
    /// First stop seen after the fault began, and first computed command after it ended.
    first_stop: Option<Duration>,
    back: Option<Duration>,
    reopened: bool,
    /// Wall-clock time it began (the controller's log is stamped in wall-clock seconds).
    wall_s: f64,
    second: Option<Child>,
    second_said: Option<(Option<i32>, String)>,
    /// Computed commands after the fault that are the replacement network's answer.
    replacement_answers: u32,
}

/// What the main loop must do now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    None,
    /// Drop the camera ports now (the publisher "dies").
    ClosePublisher,
    /// Open them again, sequence numbers from 0.
    ReopenPublisher,
}

#[derive(Debug)]
pub struct FaultPlan {
    faults: Vec<Fault>,
    controller: PathBuf,
    domain: String,
    policy: PathBuf,
    network: PathBuf,
}

/// The verdict on one fault, for the summary.
#[derive(Debug)]
pub struct FaultReport {
    pub kind: FaultKind,
    pub passed: bool,
    pub detail: String,
}

impl FaultPlan {
    /// The four faults spread over (`from`, `to`): after the warm-up, before the end.
    pub fn new(
        from: Timestamp,
        to: Timestamp,
        controller: &Path,
        domain: &str,
        policy: &Path,
        network: &Path,
    ) -> Self {
        let span = to.saturating_since(from);
        let kinds = [
            FaultKind::CameraPause,
            FaultKind::PublisherRestart,
            FaultKind::SecondController,
            FaultKind::PolicyReplaced,
        ];
        let faults = kinds
            .into_iter()
            .enumerate()
            .map(|(i, kind)| Fault {
                kind,
                at: from + span * (i as u32 + 1) / 5,
                started: false,
                first_stop: None,
                back: None,
                reopened: false,
                wall_s: f64::INFINITY,
                second: None,
                second_said: None,
                replacement_answers: 0,
            })
            .collect();
        Self {
            faults,
            controller: controller.to_owned(),
            domain: domain.to_owned(),
            policy: policy.to_owned(),
            network: network.to_owned(),
        }
    }

    /// Whether the cameras publish at `now` (not during a pause or a publisher's absence).
    pub fn cameras_publish(&self, now: Timestamp) -> bool {
        self.faults.iter().all(|fault| {
            let window = match fault.kind {
                FaultKind::CameraPause => PAUSE,
                FaultKind::PublisherRestart => RESTART_GAP,
                _ => return true,
            };
            now < fault.at || now >= fault.at + window
        })
    }

    /// Starts what is due; returns what the publisher must do.
    pub fn poll(&mut self, now: Timestamp) -> anyhow::Result<Action> {
        let mut action = Action::None;
        for fault in &mut self.faults {
            if !fault.started && now >= fault.at {
                fault.started = true;
                fault.wall_s = wall_clock_s();
                match fault.kind {
                    FaultKind::CameraPause => {}
                    FaultKind::PublisherRestart => action = Action::ClosePublisher,
                    FaultKind::SecondController => {
                        fault.second = Some(
                            Command::new(&self.controller)
                                .args(["run", "--clock", "monotonic", "--no-lock-memory"])
                                .args(["--domain", &self.domain])
                                .arg("--policy")
                                .arg(&self.policy)
                                .stdin(Stdio::null())
                                .stdout(Stdio::piped())
                                .stderr(Stdio::piped())
                                .spawn()?,
                        );
                    }
                    FaultKind::PolicyReplaced => {
                        // As a copy tool replaces a file: a new one renamed over the old.
                        let staged = self.network.with_extension("onnx.new");
                        std::fs::write(&staged, replacement_network())?;
                        std::fs::rename(&staged, &self.network)?;
                    }
                }
            }
            if fault.kind == FaultKind::PublisherRestart
                && fault.started
                && fault.back.is_none()
                && now >= fault.at + RESTART_GAP
                && action == Action::None
                && !fault.reopened
            {
                action = Action::ReopenPublisher;
                fault.reopened = true;
            }
            if let Some(child) = &mut fault.second
                && let Some(status) = child.try_wait()?
            {
                let output = fault
                    .second
                    .take()
                    .map(Child::wait_with_output)
                    .transpose()?;
                let stderr = output
                    .map(|o| String::from_utf8_lossy(&o.stderr).into_owned())
                    .unwrap_or_default();
                fault.second_said = Some((status.code(), stderr));
            }
        }
        Ok(action)
    }

    /// Sees every command: times the stop and the return that each fault must cause.
    pub fn on_command(&mut self, command: &MotionCommand, now: Timestamp) {
        for fault in &mut self.faults {
            if !fault.started {
                continue;
            }
            let since = now.saturating_since(fault.at);
            if fault.kind == FaultKind::PolicyReplaced
                && command.is_new()
                && command.speed.as_array() == REPLACEMENT
            {
                fault.replacement_answers += 1;
            }
            if since > SETTLE + PAUSE {
                continue;
            }
            if command.is_stop() && fault.first_stop.is_none() {
                fault.first_stop = Some(since);
            }
            let ended = match fault.kind {
                FaultKind::CameraPause => PAUSE,
                FaultKind::PublisherRestart => RESTART_GAP,
                _ => Duration::ZERO,
            };
            if command.is_new() && !command.is_stop() && since > ended && fault.back.is_none() {
                fault.back = Some(since);
            }
        }
    }

    /// The verdict on each fault, from what was seen and the controller's log.
    pub fn reports(&mut self, controller_log: &str) -> Vec<FaultReport> {
        let mut reports = Vec::new();
        for fault in &mut self.faults {
            let logged = logged_after(controller_log, fault.kind.log_event(), fault.wall_s);
            let ms = |d: Option<Duration>| {
                d.map_or("never".to_owned(), |d| format!("{} ms", d.as_millis()))
            };
            let (passed, detail) = match fault.kind {
                FaultKind::CameraPause => {
                    let stopped = fault.first_stop.is_some_and(|d| d <= stop_within());
                    let silent = logged_after(controller_log, "event=cameras_silent", fault.wall_s);
                    (
                        stopped && fault.back.is_some() && logged && silent,
                        format!(
                            "stopped after {} (allowed {} ms), computing again {} after the pause began; logged cameras_silent: {silent}, cameras_back: {logged}",
                            ms(fault.first_stop),
                            stop_within().as_millis(),
                            ms(fault.back)
                        ),
                    )
                }
                FaultKind::PublisherRestart => (
                    fault.first_stop.is_some_and(|d| d <= stop_within())
                        && fault.back.is_some()
                        && logged,
                    format!(
                        "stopped after {} (allowed {} ms), computing again {} after the publisher went away; logged camera_resynced: {logged}",
                        ms(fault.first_stop),
                        stop_within().as_millis(),
                        ms(fault.back)
                    ),
                ),
                FaultKind::SecondController => {
                    if let Some(child) = &mut fault.second {
                        let _ = child.kill();
                    }
                    match &fault.second_said {
                        Some((code, stderr)) => {
                            let refused = *code == Some(1)
                                && stderr.contains("another controller runs in it");
                            (
                                refused && fault.first_stop.is_none(),
                                format!(
                                    "exit code {code:?}, said: {}; the running controller stopped: {}",
                                    stderr
                                        .lines()
                                        .find(|l| l.contains("event=failed"))
                                        .unwrap_or("")
                                        .trim(),
                                    fault.first_stop.is_some()
                                ),
                            )
                        }
                        None => (false, "the second controller did not exit".to_owned()),
                    }
                }
                FaultKind::PolicyReplaced => (
                    logged
                        && fault.first_stop.is_none()
                        && fault.back.is_some()
                        && fault.replacement_answers == 0,
                    format!(
                        "commands went on (first stop after: {}); commands that were the new file's answer: {}; logged policy_file_changed: {logged}",
                        ms(fault.first_stop),
                        fault.replacement_answers
                    ),
                ),
            };
            reports.push(FaultReport {
                kind: fault.kind,
                passed,
                detail,
            });
        }
        reports
    }
}

fn wall_clock_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// Whether the log has `event` on a line stamped (`ts=`, RFC 3339) at or after `wall_s`.
fn logged_after(log: &str, event: &str, wall_s: f64) -> bool {
    log.lines().any(|line| {
        line.contains(event)
            && line
                .strip_prefix("ts=")
                .and_then(|rest| rest.split_whitespace().next())
                .and_then(|ts| OffsetDateTime::parse(ts, &Rfc3339).ok())
                .is_some_and(|ts| {
                    (ts - OffsetDateTime::UNIX_EPOCH).as_seconds_f64() >= wall_s - 0.000_001
                })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
    use dribble_controller::{BottomThumbnail, Policy, PolicyInput, TopThumbnail};

    #[test]
    fn the_replacement_is_a_policy_the_controller_would_load_and_it_answers_its_constant() {
        let fixture = crate::package_dir().join("models/fixtures/cnn");
        let directory =
            std::env::temp_dir().join(format!("dribble-replacement-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&directory);
        std::fs::create_dir_all(&directory).expect("scratch directory");
        std::fs::copy(fixture.join("policy.toml"), directory.join("policy.toml")).expect("copy");
        std::fs::write(directory.join("policy.onnx"), replacement_network()).expect("write");
        for engine in [Engine::Tract, Engine::Compiled] {
            let options = EngineOptions { engine, isa: None };
            let (mut policy, _) = OnnxPolicy::load_with(&directory.join("policy.toml"), options)
                .expect("the replacement loads");
            let (mut top, bottom) = (TopThumbnail::black(), BottomThumbnail::black());
            top.as_bytes_mut().fill(200);
            let out = policy
                .step(PolicyInput::at_rest(&top, &bottom))
                .expect("a step");
            assert_eq!([out.forward, out.left, out.turn], REPLACEMENT, "{engine:?}");
        }
        std::fs::remove_dir_all(directory).expect("clean up");
    }

    #[test]
    fn only_events_after_the_fault_count() {
        let log = "ts=1970-01-01T00:01:40.000000Z level=info event=cameras_back\n\
                   ts=1970-01-01T00:03:20.5Z level=warn event=policy_file_changed path=x\n";
        assert!(logged_after(log, "event=cameras_back", 99.0));
        assert!(!logged_after(log, "event=cameras_back", 150.0));
        assert!(logged_after(log, "event=policy_file_changed", 200.4999));
        assert!(!logged_after(log, "event=policy_file_changed", 200.5001));
        assert!(!logged_after(log, "event=camera_resynced", 0.0));
    }
}
