//! Both transports carry the lock-step protocol the same way: frames and a tick in, the
//! answering command out, episodes reset, stops when the simulator falls silent.
//! The iceoryx2 cases use a domain of their own, so tests running at once do not meet.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use dribble_controller::policy::BrightnessPolicy;
use dribble_controller::transport::channel::channel_transport;
use dribble_controller::transport::ipc::{Domain, Iceoryx2ControllerPorts, Iceoryx2SimulatorPorts};
use dribble_controller::transport::{
    ControllerNode, ControllerPorts, LockStepTick, SimulatorPorts, TransportError,
};
use dribble_controller::{
    BottomFrame, CommandFlags, ControlLoop, LoopConfig, ManualClock, MotionCommand, Timestamp,
    TopFrame,
};

const ANSWER: Duration = Duration::from_secs(5);

/// A lock-step exchange as the simulator makes it, over either transport.
fn exchange(sim: &mut dyn SimulatorPorts, tick: &LockStepTick) -> Option<MotionCommand> {
    sim.discard_commands().expect("discard");
    sim.publish_tick(tick).expect("publish tick");
    let deadline = Instant::now() + ANSWER;
    while Instant::now() < deadline {
        if let Some(command) = sim.answer(tick, Duration::from_millis(10)).expect("answer") {
            return Some(command);
        }
    }
    None
}

/// Any command at all within `timeout` (a watchdog stop has no tick to answer).
fn any_command(sim: &mut dyn SimulatorPorts, timeout: Duration) -> Option<MotionCommand> {
    let deadline = Instant::now() + timeout;
    while Instant::now() < deadline {
        if let Some(command) = sim
            .next_command(Duration::from_millis(10))
            .expect("receive")
        {
            return Some(command);
        }
    }
    None
}

struct Controller {
    stop: Arc<AtomicBool>,
    thread: JoinHandle<Result<u64, TransportError>>,
}

impl Controller {
    /// Stops the loop and returns how many watchdog stops it published.
    fn stop(self) -> u64 {
        self.stop.store(true, Ordering::Release);
        self.thread
            .join()
            .expect("controller thread")
            .expect("controller loop")
    }
}

fn spawn_controller<T, F>(open: F) -> Controller
where
    T: dribble_controller::transport::ControllerPorts,
    F: FnOnce() -> T + Send + 'static,
{
    let stop = Arc::new(AtomicBool::new(false));
    let thread_stop = Arc::clone(&stop);
    let thread = std::thread::spawn(move || {
        let control = ControlLoop::new(
            LoopConfig::default(),
            BrightnessPolicy::default(),
            ManualClock::default(),
        );
        let mut node = ControllerNode::new(control, open());
        node.run_lock_step(&thread_stop, |_| {})?;
        Ok(node.counters().watchdog_stops)
    });
    Controller { stop, thread }
}

fn tick(episode: u64, index: u64) -> LockStepTick {
    LockStepTick {
        episode,
        index,
        time_ns: (index + 1) * 10_000_000,
    }
}

/// The protocol, seen from the simulator.
fn lock_step_scenario(sim: &mut dyn SimulatorPorts) {
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    top.as_bytes_mut().fill(200);
    bottom.as_bytes_mut().fill(230);

    // No frames yet: the answer is a stop, stamped with the tick's time.
    let first = exchange(sim, &tick(1, 0)).expect("an answer to tick 0");
    assert!(first.is_stop());
    assert_eq!(first.timestamp(), Timestamp::from_nanos(10_000_000));

    // Both cameras: a new command from these very frames.
    top.restamp(0, Timestamp::from_nanos(15_000_000));
    bottom.restamp(0, Timestamp::from_nanos(16_000_000));
    sim.publish_top(&top).expect("top");
    sim.publish_bottom(&bottom).expect("bottom");
    let computed = exchange(sim, &tick(1, 1)).expect("an answer to tick 1");
    assert!(computed.is_new() && !computed.is_stop(), "{computed:?}");
    assert_eq!((computed.top_sequence, computed.bottom_sequence), (0, 0));
    assert!(
        computed.speed.forward() > 0.0,
        "a bright bottom image walks forward"
    );

    // Only the newest of two top frames counts; without a new bottom frame it repeats.
    top.restamp(1, Timestamp::from_nanos(20_000_000));
    sim.publish_top(&top).expect("top");
    top.restamp(2, Timestamp::from_nanos(21_000_000));
    sim.publish_top(&top).expect("top");
    let repeated = exchange(sim, &tick(1, 2)).expect("an answer to tick 2");
    assert!(repeated.is_repeated());
    bottom.restamp(1, Timestamp::from_nanos(25_000_000));
    sim.publish_bottom(&bottom).expect("bottom");
    let next = exchange(sim, &tick(1, 3)).expect("an answer to tick 3");
    assert_eq!((next.top_sequence, next.bottom_sequence), (2, 1));

    // A new episode starts afresh: the old frames do not count, the clock starts again.
    let restarted = exchange(sim, &tick(2, 0)).expect("an answer in episode 2");
    assert!(
        restarted.is_stop() && !restarted.is_repeated(),
        "{restarted:?}"
    );
    assert_eq!(restarted.timestamp(), Timestamp::from_nanos(10_000_000));
    assert!(
        restarted.sequence > next.sequence,
        "command sequences go on"
    );
}

/// The simulator falls silent: stops come after the silence limit; ticks then carry on.
fn silence_scenario(sim: &mut dyn SimulatorPorts) {
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    top.as_bytes_mut().fill(200);
    top.restamp(0, Timestamp::from_nanos(1));
    bottom.restamp(0, Timestamp::from_nanos(1));
    sim.publish_top(&top).expect("top");
    sim.publish_bottom(&bottom).expect("bottom");
    // The controller hears the tick after this instant, so its silence starts later.
    let silent_since = Instant::now();
    let moving = exchange(sim, &tick(7, 0)).expect("an answer");
    assert!(!moving.is_stop());
    let stop =
        any_command(sim, Duration::from_secs(5)).expect("a stop while the simulator is silent");
    let waited = silent_since.elapsed();
    assert!(stop.is_stop(), "{stop:?}");
    assert!(
        waited >= Duration::from_millis(100),
        "no stop before 3 camera periods: {waited:?}"
    );
    println!("first stop {waited:?} after the last tick");
    // The simulator was only slow: the next tick carries on where it was.
    let resumed = exchange(sim, &tick(7, 1)).expect("an answer after the silence");
    assert!(resumed.is_repeated() && !resumed.is_stop(), "{resumed:?}");
    assert_eq!(resumed.speed, moving.speed);
}

/// One domain per test, named after it (and the word size: the emulated 32-bit robot's
/// tests must not open a 64-bit run's leftovers), so a crashed run's files are cleaned up
/// by the next run instead of piling up.
fn domain(test: &str) -> Domain {
    Domain::new(Some(&format!("test-{test}-{}", usize::BITS))).expect("domain")
}

fn over_iceoryx2(test: &str, scenario: fn(&mut dyn SimulatorPorts)) -> u64 {
    let domain = domain(test);
    let controller_domain = domain.clone();
    let controller = spawn_controller(move || {
        Iceoryx2ControllerPorts::open(&controller_domain).expect("controller ports")
    });
    let mut sim = Iceoryx2SimulatorPorts::open(&domain, "test-simulator").expect("simulator ports");
    let deadline = Instant::now() + Duration::from_secs(10);
    while !sim.controller_connected() {
        assert!(Instant::now() < deadline, "the controller never connected");
        std::thread::sleep(Duration::from_millis(5));
    }
    scenario(&mut sim);
    controller.stop()
}

fn over_channels(scenario: fn(&mut dyn SimulatorPorts)) -> u64 {
    let (controller_ports, mut sim) = channel_transport();
    let controller = spawn_controller(move || controller_ports);
    scenario(&mut sim);
    controller.stop()
}

/// Before a run's first tick the controller's clock reads zero, and so does that tick's time:
/// a stop published in the silence before it (the simulator still starting, slower than the
/// silence limit on a busy machine) must not pass for its answer, however the two cross.
/// (It did: a run's first command was now and then that stop, and an episode played in one
/// job ended otherwise than the same episode in two.)
#[test]
fn a_stop_from_the_silence_before_the_first_tick_answers_nothing() {
    let (mut controller, mut sim) = channel_transport();
    let mut control = ControlLoop::new(
        LoopConfig::default(),
        BrightnessPolicy::default(),
        ManualClock::default(),
    );
    let first = LockStepTick {
        episode: 1,
        index: 0,
        time_ns: 0,
    };
    sim.publish_tick(&first).expect("tick");
    let stale = control.watchdog_stop();
    assert!(stale.is_stop() && stale.is_watchdog(), "{stale:?}");
    assert_eq!(stale.timestamp_ns, first.time_ns);
    controller.publish(&stale).expect("watchdog stop");
    let quiet = sim
        .answer(&first, Duration::from_millis(10))
        .expect("answer");
    assert_eq!(quiet, None, "a watchdog stop answered the tick");
    let own = MotionCommand {
        sequence: stale.sequence + 1,
        flags: CommandFlags::STOP,
        ..stale
    };
    controller.publish(&own).expect("the tick's own answer");
    let answer = sim.answer(&first, ANSWER).expect("answer");
    assert_eq!(answer, Some(own));
}

#[test]
fn lock_step_over_iceoryx2() {
    over_iceoryx2("lock-step", lock_step_scenario);
}

#[test]
fn lock_step_over_channels() {
    over_channels(lock_step_scenario);
}

#[test]
fn a_silent_simulator_gets_stops_over_iceoryx2() {
    assert!(over_iceoryx2("silence", silence_scenario) > 0);
}

#[test]
fn a_silent_simulator_gets_stops_over_channels() {
    assert!(over_channels(silence_scenario) > 0);
}

#[test]
fn a_second_controller_in_a_domain_is_refused() {
    let domain = domain("second");
    let _first = Iceoryx2ControllerPorts::open(&domain).expect("the first controller");
    let error = Iceoryx2ControllerPorts::open(&domain).expect_err("a second controller");
    assert!(
        error.to_string().contains("another controller runs in it"),
        "says why: {error}"
    );
}

#[test]
fn a_second_simulator_in_a_domain_is_refused() {
    let domain = domain("second-sim");
    let _first =
        Iceoryx2SimulatorPorts::open(&domain, "first-simulator").expect("the first simulator");
    let error =
        Iceoryx2SimulatorPorts::open(&domain, "second-simulator").expect_err("a second simulator");
    let said = error.to_string();
    assert!(
        said.contains("another simulator runs in it"),
        "says why: {said}"
    );
    assert!(said.contains("--domain"), "says what to do: {said}");
}

#[test]
fn domain_names_are_checked() {
    assert!(Domain::new(Some("robot-3_field_A")).is_ok());
    // The default domain is printed as "default"; that name, passed back, means it.
    let default = Domain::new(Some(Domain::DEFAULT_LABEL)).expect("the default domain");
    assert_eq!(default.name(), None);
    assert_eq!(default.label(), "default");
    assert_eq!(Domain::new(None).expect("default").name(), None);
    for bad in ["", "a/b", "has space", &"x".repeat(33)] {
        assert!(Domain::new(Some(bad)).is_err(), "{bad:?}");
    }
}

#[test]
fn the_fixed_rate_loop_serves_a_live_camera() {
    use dribble_controller::{Clock, MonotonicClock};
    let (controller_ports, mut sim) = channel_transport();
    let stop = Arc::new(AtomicBool::new(false));
    let thread_stop = Arc::clone(&stop);
    let controller = std::thread::spawn(move || {
        let control = ControlLoop::new(
            LoopConfig::default(),
            BrightnessPolicy::default(),
            MonotonicClock,
        );
        let mut node = ControllerNode::new(control, controller_ports);
        node.run_fixed_rate(&thread_stop, &mut [], |_| {})
            .map(|()| *node.control().counters())
    });
    // A camera driver at 30 Hz on the shared monotonic clock; the loop ticks at 100 Hz.
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    bottom.as_bytes_mut().fill(230);
    let mut computed = Vec::new();
    for sequence in 0..10 {
        top.restamp(sequence, MonotonicClock.now());
        bottom.restamp(sequence, MonotonicClock.now());
        sim.publish_top(&top).expect("top");
        sim.publish_bottom(&bottom).expect("bottom");
        let next_frame = Instant::now() + Duration::from_millis(33);
        while let Some(command) = sim
            .next_command(next_frame.saturating_duration_since(Instant::now()))
            .expect("receive")
        {
            if command.is_new() {
                computed.push(command);
            }
        }
    }
    stop.store(true, Ordering::Release);
    let counters = controller
        .join()
        .expect("controller thread")
        .expect("controller loop");
    // Every pair is computed once (at the first tick after it arrived), then repeated.
    assert!(computed.len() >= 8, "{computed:?}");
    assert!(computed.iter().all(|c| c.top_sequence == c.bottom_sequence));
    assert!(
        computed
            .windows(2)
            .all(|w| w[0].top_sequence < w[1].top_sequence)
    );
    assert!(
        counters.repeated_commands > counters.new_commands,
        "{counters:?}"
    );
}

#[test]
fn a_non_finite_command_from_shared_memory_is_refused_and_a_wild_one_clamped() {
    use dribble_controller::SpeedCommand;
    use dribble_controller::transport::ControllerPorts;
    let domain = domain("foreign-command");
    // A foreign controller: it writes whatever bytes it likes into the command sample.
    let mut foreign = Iceoryx2ControllerPorts::open(&domain).expect("controller ports");
    let mut sim = Iceoryx2SimulatorPorts::open(&domain, "test-simulator").expect("simulator ports");
    let raw_speed = |speed: [f32; 3]| {
        // SAFETY: SpeedCommand is repr(C) of three f32; this forges what another process
        // could have written into shared memory, bypassing SpeedCommand::new on purpose.
        #[allow(unsafe_code)]
        unsafe {
            std::mem::transmute::<[f32; 3], SpeedCommand>(speed)
        }
    };
    let mut command = MotionCommand::initial_stop();
    command.sequence = 7;
    command.speed = raw_speed([f32::NAN, 0.0, 0.5]);
    foreign.publish(&command).expect("publish");
    let error = sim
        .next_command(Duration::from_secs(1))
        .expect_err("a NaN speed is refused");
    assert!(
        matches!(error, TransportError::MalformedCommand { sequence: 7, .. }),
        "{error}"
    );
    assert!(error.to_string().contains("non-finite speed"), "{error}");

    command.sequence = 8;
    command.speed = raw_speed([3.0, -40.0, 0.5]);
    foreign.publish(&command).expect("publish");
    let clamped = any_command(&mut sim, Duration::from_secs(1)).expect("the command");
    assert_eq!(clamped.speed.as_array(), [1.0, -1.0, 0.5]);
}
