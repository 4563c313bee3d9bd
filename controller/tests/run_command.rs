//! The robot binary's `run`: over iceoryx2 it answers a lock-step simulator, and on SIGTERM
//! it stops cleanly with its statistics. Under `cross/test` the binary runs on the emulated
//! Atom (`DRIBBLE_TEST_RUNNER`), so this proves the shared-memory path on the robot's CPU.

mod support;

use support::controller_command;

use std::io::{BufRead, BufReader};
use std::process::Stdio;
use std::time::{Duration, Instant};

use dribble_controller::transport::ipc::{Domain, Iceoryx2SimulatorPorts};
use dribble_controller::transport::{LockStepTick, SimulatorPorts};
use dribble_controller::{BottomFrame, Timestamp, TopFrame};

#[test]
fn run_answers_lock_step_ticks_and_stops_on_sigterm() {
    let name = format!("test-run-{}", usize::BITS);
    let mut child = controller_command()
        .args(["run", "--clock", "simulation", "--domain", &name])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the controller starts");
    let stderr = child.stderr.take().expect("stderr");
    let (lines_tx, lines_rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = lines_tx.send(line);
        }
    });
    let ready = lines_rx
        .recv_timeout(Duration::from_secs(60))
        .expect("a first log line");
    assert!(
        ready.contains("event=ready") && ready.contains(&name),
        "{ready}"
    );

    let domain = Domain::new(Some(&name)).expect("domain");
    let mut sim = Iceoryx2SimulatorPorts::open(&domain, "test-simulator").expect("ports");
    let deadline = Instant::now() + Duration::from_secs(30);
    while !sim.controller_connected() {
        assert!(Instant::now() < deadline, "never connected");
        std::thread::sleep(Duration::from_millis(5));
    }
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    top.restamp(0, Timestamp::from_nanos(5_000_000));
    bottom.restamp(0, Timestamp::from_nanos(6_000_000));
    sim.publish_top(&top).expect("top");
    sim.publish_bottom(&bottom).expect("bottom");
    let tick = LockStepTick {
        episode: 42,
        index: 0,
        time_ns: 10_000_000,
    };
    sim.discard_commands().expect("discard");
    sim.publish_tick(&tick).expect("tick");
    let command = loop {
        if let Some(command) = sim
            .answer(&tick, Duration::from_millis(10))
            .expect("answer")
        {
            break command;
        }
        assert!(Instant::now() < deadline, "no answer");
    };
    assert!(command.is_new(), "{command:?}");
    assert_eq!((command.top_sequence, command.bottom_sequence), (0, 0));

    let pid = libc::pid_t::try_from(child.id()).expect("pid");
    // SAFETY: kill(2) on our own child.
    #[allow(unsafe_code)]
    let signalled = unsafe { libc::kill(pid, libc::SIGTERM) };
    assert_eq!(signalled, 0);
    let output = child.wait_with_output().expect("it stops");
    assert!(output.status.success(), "{output:?}");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("ticks 1: 1 new"), "{stdout}");
    assert!(stdout.contains("tick time: p50"), "{stdout}");
    let statistics = dribble_controller::run_statistics::RunStatistics::from_log(&stdout)
        .unwrap_or_else(|why| panic!("{why}: {stdout}"));
    assert_eq!(
        (statistics.counters.ticks, statistics.counters.new_commands),
        (1, 1)
    );
    assert!(statistics.tick_time.is_some());
    let logged: Vec<String> = lines_rx.try_iter().collect();
    assert!(
        logged
            .iter()
            .any(|l| l.contains("event=episode episode=42")),
        "{logged:?}"
    );
    assert!(
        logged.iter().any(|l| l.contains("event=stopped")),
        "{logged:?}"
    );
}
