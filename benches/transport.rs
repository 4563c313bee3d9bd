//! The transport's share of the 2 ms budget, measured through iceoryx2 shared memory:
//!
//! - a top frame (614 KB) from publish to receive: the publisher stamps the frame, copies
//!   it into a loaned sample and sends it; another thread, polling as the controller does
//!   each tick, takes it and reads the clock;
//! - a whole lock-step round trip: a top and a bottom frame and a tick out, the
//!   controller (a thread running the controller's own lock-step loop with the test policy,
//!   woken by the tick event) computes and publishes, the command comes back.
//!
//! Besides criterion's timing, p50 and p99 over many samples are printed (`cargo bench
//! --bench transport`); run as a test, each is measured a few times only.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use dribble_controller::policy::BrightnessPolicy;
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::tick_stats::TickStats;
use dribble_controller::transport::channel::channel_transport;
use dribble_controller::transport::ipc::{Domain, Iceoryx2ControllerPorts, Iceoryx2SimulatorPorts};
use dribble_controller::transport::{
    ControllerNode, ControllerPorts, LockStepTick, SimulatorPorts,
};
use dribble_controller::{
    BottomFrame, Clock, ControlLoop, LoopConfig, ManualClock, MonotonicClock, Timestamp, TopFrame,
};

fn samples() -> usize {
    if std::env::args().any(|a| a == "--bench") {
        5_000
    } else {
        10
    }
}

fn domain(name: &str) -> Domain {
    Domain::new(Some(&format!("bench-{name}"))).expect("domain")
}

fn report(what: &str, stats: &TickStats) {
    if let Some(summary) = stats.summary() {
        println!(
            "{what}: p50 {:.1?} p99 {:.1?} max {:.1?} over {} samples",
            summary.median, summary.p99, summary.max, summary.ticks
        );
    }
}

/// Publish to receive of a top frame, the receiver in another thread polling.
fn frame_latency(c: &mut Criterion) {
    let domain = domain("frame");
    let mut sim = Iceoryx2SimulatorPorts::open(&domain, "bench-camera").expect("camera ports");
    let received_ns = Arc::new(AtomicU64::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let receiver = {
        let (domain, received_ns, stop) = (domain.clone(), received_ns.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut ports = Iceoryx2ControllerPorts::open(&domain).expect("controller ports");
            while !stop.load(Ordering::Acquire) {
                if let Some(sample) = ports.newest_top().expect("receive") {
                    let frame: &TopFrame = &sample;
                    let sent = Timestamp::from_nanos(frame.header().timestamp_ns);
                    let latency = MonotonicClock.now().saturating_since(sent);
                    received_ns.store(latency.as_nanos() as u64 + 1, Ordering::Release);
                }
                std::hint::spin_loop();
            }
        })
    };
    while !sim.controller_connected() {
        std::thread::sleep(Duration::from_millis(1));
    }
    let mut top = TopFrame::new_boxed();
    TestPattern::default().paint(&mut top, 0, Timestamp::ZERO);
    let mut sequence = 0;
    let mut one = |sim: &mut Iceoryx2SimulatorPorts| -> Duration {
        sequence += 1;
        received_ns.store(0, Ordering::Release);
        top.restamp(sequence, MonotonicClock.now());
        sim.publish_top(&top).expect("publish");
        loop {
            let ns = received_ns.load(Ordering::Acquire);
            if ns > 0 {
                return Duration::from_nanos(ns - 1);
            }
            std::hint::spin_loop();
        }
    };
    let mut stats = TickStats::new(Duration::from_millis(2));
    for _ in 0..samples() {
        stats.record(one(&mut sim));
    }
    report("top frame, publish to receive (iceoryx2)", &stats);
    c.bench_function("iceoryx2 top frame publish to receive", |b| {
        b.iter_custom(|iterations| (0..iterations).map(|_| one(&mut sim)).sum())
    });
    stop.store(true, Ordering::Release);
    receiver.join().expect("receiver");
}

/// One lock-step round trip as the simulator makes it, over either transport.
fn round_trip(
    sim: &mut dyn SimulatorPorts,
    top: &TopFrame,
    bottom: &BottomFrame,
    tick: &LockStepTick,
) {
    sim.discard_commands().expect("discard");
    sim.publish_top(top).expect("top");
    sim.publish_bottom(bottom).expect("bottom");
    sim.publish_tick(tick).expect("tick");
    while sim
        .answer(tick, Duration::from_millis(100))
        .expect("answer")
        .is_none()
    {}
}

fn run_controller<T: ControllerPorts>(ports: T, stop: &AtomicBool) {
    let control = ControlLoop::new(
        LoopConfig::default(),
        BrightnessPolicy::default(),
        ManualClock::default(),
    );
    ControllerNode::new(control, ports)
        .run_lock_step(stop, |_| {})
        .expect("controller loop");
}

fn measure_round_trips(c: &mut Criterion, name: &str, sim: &mut dyn SimulatorPorts) {
    let pattern = TestPattern::default();
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    let mut index = 0;
    let mut one = |sim: &mut dyn SimulatorPorts| -> Duration {
        // Both cameras new each time: every tick computes (thumbnails + policy).
        let time = Timestamp::from_nanos((index + 1) * 10_000_000);
        pattern.paint(&mut top, index, time);
        pattern.paint(&mut bottom, index, time);
        let tick = LockStepTick {
            episode: 1,
            index,
            time_ns: time.as_nanos(),
        };
        index += 1;
        let started = Instant::now();
        round_trip(sim, &top, &bottom, &tick);
        started.elapsed()
    };
    let mut stats = TickStats::new(Duration::from_millis(2));
    for _ in 0..samples() {
        stats.record(one(sim));
    }
    report(&format!("lock-step round trip ({name})"), &stats);
    c.bench_function(&format!("lock-step round trip {name}"), |b| {
        b.iter_custom(|iterations| (0..iterations).map(|_| one(sim)).sum())
    });
}

fn lock_step(c: &mut Criterion) {
    let domain = domain("lock-step");
    let stop = Arc::new(AtomicBool::new(false));
    let controller = {
        let (domain, stop) = (domain.clone(), stop.clone());
        std::thread::spawn(move || {
            let ports = Iceoryx2ControllerPorts::open(&domain).expect("controller ports");
            run_controller(ports, &stop);
        })
    };
    let mut sim = Iceoryx2SimulatorPorts::open(&domain, "bench-simulator").expect("sim ports");
    while !sim.controller_connected() {
        std::thread::sleep(Duration::from_millis(1));
    }
    measure_round_trips(c, "iceoryx2", &mut sim);
    stop.store(true, Ordering::Release);
    controller.join().expect("controller");

    let (controller_ports, mut sim) = channel_transport();
    let stop = Arc::new(AtomicBool::new(false));
    let controller = {
        let stop = stop.clone();
        std::thread::spawn(move || run_controller(controller_ports, &stop))
    };
    measure_round_trips(c, "in-process channels", &mut sim);
    stop.store(true, Ordering::Release);
    controller.join().expect("controller");
    drop(sim);
}

criterion_group!(benches, frame_latency, lock_step);
criterion_main!(benches);
