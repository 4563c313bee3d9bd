//! The controller's receive path and tick over a transport allocate nothing after
//! start-up: taking the tick, receiving the newest frames (read in place, in shared memory
//! for iceoryx2) and the control loop's tick. Publishing the command is counted apart:
//! nothing over channels; over iceoryx2 0.10 exactly one 48-byte block per command, the
//! reference-counted bookkeeping `Publisher::loan` makes for every sample (iceoryx2's
//! `ChunkMutSharedState`), which no public API avoids. Only the controller's calls are
//! counted; the simulator's, on the same thread, are not.

mod support;

use std::time::Duration;

use dribble_controller::policy::BrightnessPolicy;
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::transport::channel::channel_transport;
use dribble_controller::transport::ipc::{Domain, Iceoryx2ControllerPorts, Iceoryx2SimulatorPorts};
use dribble_controller::transport::{
    ControllerNode, ControllerPorts, LockStepTick, SimulatorPorts,
};
use dribble_controller::{
    BottomFrame, CameraInput, ControlLoop, LoopConfig, ManualClock, Timestamp, TopFrame,
};
use support::counting_allocator::{CountingAllocator, count_allocations};

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

/// The simulator's half of a lock-step tick, over either transport.
fn publish(
    sim: &mut dyn SimulatorPorts,
    top: &TopFrame,
    bottom: &BottomFrame,
    tick: &LockStepTick,
) {
    sim.discard_commands().expect("discard");
    sim.publish_top(top).expect("top");
    sim.publish_bottom(bottom).expect("bottom");
    sim.publish_tick(tick).expect("tick");
}

/// Allocations (count, bytes) of the controller's side in `ticks` lock-step ticks after a
/// warm-up: receive path and tick, then publishing.
#[derive(Debug, Default)]
struct Counted {
    receive_and_tick: (u64, u64),
    publish: (u64, u64),
}

fn add(total: &mut (u64, u64), more: (u64, u64)) {
    total.0 += more.0;
    total.1 += more.1;
}

fn controller_allocations<T: ControllerPorts>(
    sim: &mut dyn SimulatorPorts,
    ports: T,
    ticks: u64,
) -> Counted {
    let clock = ManualClock::default();
    let control = ControlLoop::new(
        LoopConfig::default(),
        BrightnessPolicy::default(),
        clock.clone(),
    );
    let mut node = ControllerNode::new(control, ports);
    let pattern = TestPattern::default();
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    let mut counted = Counted::default();
    for index in 0..100 + ticks {
        let time = Timestamp::from_nanos((index + 1) * 10_000_000);
        // Frames on two ticks of three, so ticks compute, repeat and take single frames.
        if index % 3 != 2 {
            pattern.paint(&mut top, index, time);
            pattern.paint(&mut bottom, index, time);
        }
        let tick = LockStepTick {
            episode: 1,
            index,
            time_ns: time.as_nanos(),
        };
        publish(sim, &top, &bottom, &tick);
        // What `ControllerNode::run_lock_step` and `serve_tick` do, in two counted parts.
        let mut command = None;
        let receive_and_tick = count_allocations(|| {
            let received = node
                .ports_mut()
                .next_tick(Duration::from_secs(1))
                .expect("tick")
                .expect("a tick is waiting");
            clock.set(received.time());
            let top = node.ports_mut().newest_top().expect("top");
            let bottom = node.ports_mut().newest_bottom().expect("bottom");
            command = Some(node.control_mut().tick(CameraInput {
                top: top.as_deref(),
                bottom: bottom.as_deref(),
            }));
        });
        let command = command.expect("a command");
        let publish = count_allocations(|| node.ports_mut().publish(&command).expect("publish"));
        if index >= 100 {
            add(&mut counted.receive_and_tick, receive_and_tick);
            add(&mut counted.publish, publish);
        }
        let answer = sim.answer(&tick, Duration::from_secs(1)).expect("answer");
        assert_eq!(answer, Some(command));
    }
    let counters = node.control().counters();
    assert!(counters.new_commands > ticks / 2, "{counters:?}");
    counted
}

#[test]
fn receive_and_tick_over_iceoryx2_allocate_nothing() {
    support::install_log_subscriber();
    let domain = Domain::new(Some("test-allocations")).expect("domain");
    let ports = Iceoryx2ControllerPorts::open(&domain).expect("controller ports");
    let mut sim = Iceoryx2SimulatorPorts::open(&domain, "alloc-simulator").expect("sim ports");
    let counted = controller_allocations(&mut sim, ports, 2_000);
    println!("iceoryx2, 2,000 controller ticks after warm-up: {counted:?}");
    assert_eq!(counted.receive_and_tick, (0, 0), "receive path and tick");
    assert_eq!(counted.publish, (2_000, 2_000 * 48), "one loan per command");
}

#[test]
fn a_whole_tick_over_channels_allocates_nothing() {
    support::install_log_subscriber();
    let (ports, mut sim) = channel_transport();
    let counted = controller_allocations(&mut sim, ports, 2_000);
    println!("channels, 2,000 controller ticks after warm-up: {counted:?}");
    assert_eq!(counted.receive_and_tick, (0, 0), "receive path and tick");
    assert_eq!(counted.publish, (0, 0), "publishing");
}
