//! The iceoryx2 transport: zero-copy shared memory between processes.
//!
//! Services (DESIGN.md, "Shared memory"), all publish-subscribe of `#[repr(C)]` messages
//! without pointers, with the iceoryx2 type names given here so that a C or C++ program can
//! open them:
//!
//! | service                  | message        | type name               | bytes   |
//! |--------------------------|----------------|-------------------------|---------|
//! | `dribble/camera/top`     | [`TopFrame`]     | `dribble::TopFrame`     | 614,432 |
//! | `dribble/camera/bottom`  | [`BottomFrame`]  | `dribble::BottomFrame`  | 153,632 |
//! | `dribble/motion/command` | [`MotionCommand`]| `dribble::MotionCommand`| 48      |
//! | `dribble/sim/tick`       | [`LockStepTick`] | `dribble::LockStepTick` | 24      |
//!
//! `dribble/motion/command` and `dribble/sim/tick` also exist as event services: the
//! controller notifies after each command, the simulator after each tick, so the waiting
//! side sleeps instead of polling. Frame layouts are in [`crate::frame`], the command's in
//! [`crate::motion_command`], the tick's in [`LockStepTick`].
//!
//! A [`Domain`] keeps one robot's (or one test's) services apart from another's on the same
//! machine. Dead nodes (a killed process) are cleaned up by whichever node starts next.

use core::time::Duration;

use iceoryx2::node::NodeView;
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;

use super::{ControllerPorts, LockStepTick, SimulatorPorts, TransportError};
use crate::frame::{BottomFrame, FrameHeader, TopFrame};
use crate::motion_command::MotionCommand;

pub const TOP_CAMERA_SERVICE: &str = "dribble/camera/top";
pub const BOTTOM_CAMERA_SERVICE: &str = "dribble/camera/bottom";
pub const COMMAND_SERVICE: &str = "dribble/motion/command";
pub const TICK_SERVICE: &str = "dribble/sim/tick";

/// The controller's node name, by which the simulator finds it and watches it.
pub const CONTROLLER_NODE: &str = "dribble-controller";
pub const SIMULATOR_NODE: &str = "dribble-simulator";

// SAFETY (all four): `#[repr(C)]` structs of integers, floats and byte arrays, without
// pointers, references or handles; their layouts are fixed by tests on every target.
#[allow(unsafe_code)]
unsafe impl ZeroCopySend for FrameHeader {
    unsafe fn type_name() -> &'static str {
        "dribble::FrameHeader"
    }
}
#[allow(unsafe_code)]
unsafe impl ZeroCopySend for TopFrame {
    unsafe fn type_name() -> &'static str {
        "dribble::TopFrame"
    }
}
#[allow(unsafe_code)]
unsafe impl ZeroCopySend for BottomFrame {
    unsafe fn type_name() -> &'static str {
        "dribble::BottomFrame"
    }
}
#[allow(unsafe_code)]
unsafe impl ZeroCopySend for MotionCommand {
    unsafe fn type_name() -> &'static str {
        "dribble::MotionCommand"
    }
}
#[allow(unsafe_code)]
unsafe impl ZeroCopySend for LockStepTick {
    unsafe fn type_name() -> &'static str {
        "dribble::LockStepTick"
    }
}

type Ipc = ipc::Service;

/// One set of services, apart from every other set on the machine: iceoryx2's default
/// configuration (what any other iceoryx2 program opens), or a named domain.
#[derive(Clone, Debug)]
pub struct Domain {
    name: Option<String>,
    config: Config,
}

/// A node seen in a domain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NodeInfo {
    pub id: iceoryx2::identifiers::UniqueNodeId,
    pub pid: Option<i32>,
    pub alive: bool,
}

impl Domain {
    /// The environment variable that names the domain when no flag does.
    pub const ENV: &str = "DRIBBLE_DOMAIN";
    /// Where iceoryx2 keeps its node and service files, if not in `/tmp/iceoryx2/` (an
    /// emulated robot needs them on tmpfs, e.g. `/dev/shm/iceoryx2/`).
    pub const ROOT_ENV: &str = "DRIBBLE_IPC_ROOT";

    /// The default domain (`None`) or a named one: letters, digits, `-` and `_`, at most 32.
    pub fn new(name: Option<&str>) -> Result<Self, TransportError> {
        let mut config = Config::default();
        // Dead nodes are cleaned up explicitly, so that a start can say what it cleaned.
        config.global.node.cleanup_dead_nodes_on_creation = false;
        if let Some(root) = std::env::var_os(Self::ROOT_ENV).filter(|r| !r.is_empty()) {
            let mut root = root.to_string_lossy().into_owned();
            if !root.ends_with('/') {
                root.push('/');
            }
            let path = iceoryx2::prelude::Path::new(root.as_bytes())
                .map_err(|e| TransportError::ipc("invalid DRIBBLE_IPC_ROOT", e))?;
            config.global.set_root_path(&path);
        }
        if let Some(name) = name {
            let valid = !name.is_empty()
                && name.len() <= 32
                && name
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
            if !valid {
                return Err(TransportError::ipc(
                    "invalid domain name (letters, digits, '-', '_'; 1 to 32)",
                    name,
                ));
            }
            config.global.prefix = FileName::new(format!("iox2_{name}_").as_bytes())
                .map_err(|e| TransportError::ipc("invalid domain name", e))?;
        }
        Ok(Self {
            name: name.map(str::to_owned),
            config,
        })
    }

    /// The domain named by `DRIBBLE_DOMAIN`, or the default one.
    pub fn from_env() -> Result<Self, TransportError> {
        let name = std::env::var(Self::ENV).ok().filter(|n| !n.is_empty());
        Self::new(name.as_deref())
    }

    pub fn name(&self) -> &str {
        self.name.as_deref().unwrap_or("default")
    }

    pub fn config(&self) -> &Config {
        &self.config
    }

    /// A node of this domain, after removing what dead nodes left behind; also returns how
    /// many dead nodes were cleaned up.
    pub fn create_node(&self, name: &str) -> Result<(Node<Ipc>, u64), TransportError> {
        let node_name =
            NodeName::new(name).map_err(|e| TransportError::ipc("invalid node name", e))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&self.config)
            // The binaries handle SIGINT and SIGTERM themselves.
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .map_err(|e| TransportError::ipc("cannot create the iceoryx2 node", e))?;
        let cleaned = node.try_cleanup_dead_nodes();
        Ok((node, cleaned.cleanups))
    }

    /// The nodes called `name` in this domain, alive or dead.
    pub fn nodes_named(&self, name: &str) -> Result<Vec<NodeInfo>, TransportError> {
        let mut found = Vec::new();
        Node::<Ipc>::list(&self.config, |state| {
            let (view, alive) = match &state {
                NodeState::Alive(view) => (Some(view.details()), true),
                NodeState::Dead(view) => (Some(view.details()), false),
                NodeState::Inaccessible(_) | NodeState::Undefined(_) => (None, false),
            };
            if let Some(Some(details)) = view
                && details.name().as_str() == name
            {
                found.push(NodeInfo {
                    id: *state.node_id(),
                    pid: Some(details.process_id().value()),
                    alive,
                });
            }
            CallbackProgression::Continue
        })
        .map_err(|e| TransportError::ipc("cannot list the iceoryx2 nodes", e))?;
        Ok(found)
    }

    /// Whether the node `id` still runs: false once its process died, even if nobody has
    /// cleaned up after it yet.
    pub fn is_alive(
        &self,
        id: iceoryx2::identifiers::UniqueNodeId,
    ) -> Result<bool, TransportError> {
        let state = Node::<Ipc>::state_of(&self.config, id)
            .map_err(|e| TransportError::ipc("cannot look up an iceoryx2 node", e))?;
        Ok(matches!(state, Some(NodeState::Alive(_))))
    }
}

/// Quality of service of each service. Both sides open them with these, so they agree.
struct Qos {
    max_publishers: usize,
    max_subscribers: usize,
    buffer: usize,
}

const FRAME_QOS: Qos = Qos {
    max_publishers: 2,
    max_subscribers: 4,
    buffer: 2,
};
/// One controller per robot: a second one cannot publish commands.
const COMMAND_QOS: Qos = Qos {
    max_publishers: 1,
    max_subscribers: 4,
    buffer: 4,
};
const TICK_QOS: Qos = Qos {
    max_publishers: 1,
    max_subscribers: 2,
    buffer: 2,
};

fn open_pubsub<T: core::fmt::Debug + ZeroCopySend + 'static>(
    node: &Node<Ipc>,
    name: &'static str,
    qos: &Qos,
) -> Result<PubSubFactory<Ipc, T, ()>, TransportError> {
    let service_name =
        ServiceName::new(name).map_err(|e| TransportError::ipc("invalid service name", e))?;
    node.service_builder(&service_name)
        .publish_subscribe::<T>()
        .max_publishers(qos.max_publishers)
        .max_subscribers(qos.max_subscribers)
        .subscriber_max_buffer_size(qos.buffer)
        .subscriber_max_borrowed_samples(2)
        .history_size(0)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| TransportError::ipc(name, e))
}

fn open_event(
    node: &Node<Ipc>,
    name: &'static str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<Ipc>, TransportError> {
    let service_name =
        ServiceName::new(name).map_err(|e| TransportError::ipc("invalid service name", e))?;
    node.service_builder(&service_name)
        .event()
        .max_notifiers(4)
        .max_listeners(4)
        .open_or_create()
        .map_err(|e| TransportError::ipc(name, e))
}

fn subscriber<T: core::fmt::Debug + ZeroCopySend + 'static>(
    factory: &PubSubFactory<Ipc, T, ()>,
    name: &'static str,
) -> Result<Subscriber<Ipc, T, ()>, TransportError> {
    factory
        .subscriber_builder()
        .create()
        .map_err(|e| TransportError::ipc(name, e))
}

fn publisher<T: core::fmt::Debug + ZeroCopySend + 'static>(
    factory: &PubSubFactory<Ipc, T, ()>,
    name: &'static str,
) -> Result<Publisher<Ipc, T, ()>, TransportError> {
    factory
        .publisher_builder()
        .max_loaned_samples(1)
        .create()
        .map_err(|e| TransportError::ipc(name, e))
}

/// Sleeps until the other side signals, at most `timeout`. A signal (SIGINT, SIGTERM)
/// only cuts the wait short: the caller's loop looks at its stop flag next.
fn wait_for_event(
    listener: &Listener<Ipc>,
    timeout: Duration,
    what: &'static str,
) -> Result<(), TransportError> {
    match listener.timed_wait(|_| {}, timeout) {
        Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(()),
        Err(e) => Err(TransportError::ipc(what, e)),
    }
}

/// Receives everything waiting and keeps the newest: older samples go back at once.
fn newest<T: core::fmt::Debug + ZeroCopySend>(
    subscriber: &Subscriber<Ipc, T, ()>,
) -> Result<Option<Sample<Ipc, T, ()>>, TransportError> {
    let mut newest = None;
    loop {
        match subscriber.receive() {
            Ok(Some(sample)) => newest = Some(sample),
            Ok(None) => return Ok(newest),
            Err(e) => return Err(TransportError::ipc("receive failed", e)),
        }
    }
}

/// The controller's side: subscribes to both cameras and the simulator's ticks, publishes
/// commands.
#[derive(Debug)]
pub struct Iceoryx2ControllerPorts {
    node: Node<Ipc>,
    top: Subscriber<Ipc, TopFrame, ()>,
    bottom: Subscriber<Ipc, BottomFrame, ()>,
    ticks: Subscriber<Ipc, LockStepTick, ()>,
    tick_events: Listener<Ipc>,
    commands: Publisher<Ipc, MotionCommand, ()>,
    command_events: Notifier<Ipc>,
    cleaned_dead_nodes: u64,
}

impl Iceoryx2ControllerPorts {
    pub fn open(domain: &Domain) -> Result<Self, TransportError> {
        let (node, cleaned_dead_nodes) = domain.create_node(CONTROLLER_NODE)?;
        let top = open_pubsub::<TopFrame>(&node, TOP_CAMERA_SERVICE, &FRAME_QOS)?;
        let bottom = open_pubsub::<BottomFrame>(&node, BOTTOM_CAMERA_SERVICE, &FRAME_QOS)?;
        let ticks = open_pubsub::<LockStepTick>(&node, TICK_SERVICE, &TICK_QOS)?;
        let commands = open_pubsub::<MotionCommand>(&node, COMMAND_SERVICE, &COMMAND_QOS)?;
        let commands = publisher(&commands, COMMAND_SERVICE).map_err(|e| match e {
            TransportError::Ipc { detail, .. } => TransportError::Ipc {
                what: "cannot publish commands (is another controller running in this domain?)",
                detail,
            },
            other => other,
        })?;
        let tick_events = open_event(&node, TICK_SERVICE)?
            .listener_builder()
            .create()
            .map_err(|e| TransportError::ipc(TICK_SERVICE, e))?;
        let command_events = open_event(&node, COMMAND_SERVICE)?
            .notifier_builder()
            .create()
            .map_err(|e| TransportError::ipc(COMMAND_SERVICE, e))?;
        Ok(Self {
            top: subscriber(&top, TOP_CAMERA_SERVICE)?,
            bottom: subscriber(&bottom, BOTTOM_CAMERA_SERVICE)?,
            ticks: subscriber(&ticks, TICK_SERVICE)?,
            tick_events,
            commands,
            command_events,
            node,
            cleaned_dead_nodes,
        })
    }

    /// How many dead nodes (killed processes) this start cleaned up after.
    pub fn cleaned_dead_nodes(&self) -> u64 {
        self.cleaned_dead_nodes
    }

    pub fn node(&self) -> &Node<Ipc> {
        &self.node
    }
}

impl ControllerPorts for Iceoryx2ControllerPorts {
    type Top = Sample<Ipc, TopFrame, ()>;
    type Bottom = Sample<Ipc, BottomFrame, ()>;

    fn newest_top(&mut self) -> Result<Option<Self::Top>, TransportError> {
        newest(&self.top)
    }

    fn newest_bottom(&mut self) -> Result<Option<Self::Bottom>, TransportError> {
        newest(&self.bottom)
    }

    fn publish(&mut self, command: &MotionCommand) -> Result<(), TransportError> {
        self.commands
            .send_copy(*command)
            .map_err(|e| TransportError::ipc("cannot publish a command", e))?;
        self.command_events
            .notify()
            .map_err(|e| TransportError::ipc("cannot signal a command", e))?;
        Ok(())
    }

    fn next_tick(&mut self, timeout: Duration) -> Result<Option<LockStepTick>, TransportError> {
        if let Some(tick) = self.receive_tick()? {
            return Ok(Some(tick));
        }
        wait_for_event(&self.tick_events, timeout, "waiting for a tick failed")?;
        self.receive_tick()
    }
}

impl Iceoryx2ControllerPorts {
    fn receive_tick(&mut self) -> Result<Option<LockStepTick>, TransportError> {
        match self.ticks.receive() {
            Ok(sample) => Ok(sample.map(|s| *s)),
            Err(e) => Err(TransportError::ipc("receive failed", e)),
        }
    }
}

/// The simulator's (or camera driver's and motion module's) side over iceoryx2.
#[derive(Debug)]
pub struct Iceoryx2SimulatorPorts {
    node: Node<Ipc>,
    top_service: PubSubFactory<Ipc, TopFrame, ()>,
    tick_service: PubSubFactory<Ipc, LockStepTick, ()>,
    command_service: PubSubFactory<Ipc, MotionCommand, ()>,
    top: Publisher<Ipc, TopFrame, ()>,
    bottom: Publisher<Ipc, BottomFrame, ()>,
    ticks: Publisher<Ipc, LockStepTick, ()>,
    tick_events: Notifier<Ipc>,
    commands: Subscriber<Ipc, MotionCommand, ()>,
    command_events: Listener<Ipc>,
    cleaned_dead_nodes: u64,
}

impl Iceoryx2SimulatorPorts {
    pub fn open(domain: &Domain, node_name: &str) -> Result<Self, TransportError> {
        let (node, cleaned_dead_nodes) = domain.create_node(node_name)?;
        let top_service = open_pubsub::<TopFrame>(&node, TOP_CAMERA_SERVICE, &FRAME_QOS)?;
        let bottom = open_pubsub::<BottomFrame>(&node, BOTTOM_CAMERA_SERVICE, &FRAME_QOS)?;
        let tick_service = open_pubsub::<LockStepTick>(&node, TICK_SERVICE, &TICK_QOS)?;
        let command_service = open_pubsub::<MotionCommand>(&node, COMMAND_SERVICE, &COMMAND_QOS)?;
        let tick_events = open_event(&node, TICK_SERVICE)?
            .notifier_builder()
            .create()
            .map_err(|e| TransportError::ipc(TICK_SERVICE, e))?;
        let command_events = open_event(&node, COMMAND_SERVICE)?
            .listener_builder()
            .create()
            .map_err(|e| TransportError::ipc(COMMAND_SERVICE, e))?;
        Ok(Self {
            top: publisher(&top_service, TOP_CAMERA_SERVICE)?,
            bottom: publisher(&bottom, BOTTOM_CAMERA_SERVICE)?,
            ticks: publisher(&tick_service, TICK_SERVICE)?,
            commands: subscriber(&command_service, COMMAND_SERVICE)?,
            top_service,
            tick_service,
            command_service,
            tick_events,
            command_events,
            node,
            cleaned_dead_nodes,
        })
    }

    pub fn cleaned_dead_nodes(&self) -> u64 {
        self.cleaned_dead_nodes
    }

    pub fn node(&self) -> &Node<Ipc> {
        &self.node
    }

    /// Whether a controller has opened its ports: it subscribes to the cameras and ticks and
    /// publishes commands. Samples sent before that are lost, so a lock-step simulator waits.
    pub fn controller_connected(&self) -> bool {
        self.command_service.dynamic_config().number_of_publishers() > 0
            && self.tick_service.dynamic_config().number_of_subscribers() > 0
            && self.top_service.dynamic_config().number_of_subscribers() > 0
    }

    fn receive_answer(
        &mut self,
        tick: &LockStepTick,
    ) -> Result<Option<MotionCommand>, TransportError> {
        loop {
            match self.commands.receive() {
                Ok(Some(command)) if command.timestamp_ns == tick.time_ns => {
                    return Ok(Some(*command));
                }
                Ok(Some(_)) => {} // a stop from a silent spell: it answers nothing
                Ok(None) => return Ok(None),
                Err(e) => return Err(TransportError::ipc("receive failed", e)),
            }
        }
    }

    fn receive_command(&mut self) -> Result<Option<MotionCommand>, TransportError> {
        match self.commands.receive() {
            Ok(sample) => Ok(sample.map(|s| *s)),
            Err(e) => Err(TransportError::ipc("receive failed", e)),
        }
    }
}

impl SimulatorPorts for Iceoryx2SimulatorPorts {
    fn publish_top(&mut self, frame: &TopFrame) -> Result<(), TransportError> {
        send_frame(&self.top, frame)
    }

    fn publish_bottom(&mut self, frame: &BottomFrame) -> Result<(), TransportError> {
        send_frame(&self.bottom, frame)
    }

    fn discard_commands(&mut self) -> Result<(), TransportError> {
        self.command_events
            .try_wait(|_| {})
            .map_err(|e| TransportError::ipc("cannot read command events", e))?;
        while newest(&self.commands)?.is_some() {}
        Ok(())
    }

    fn publish_tick(&mut self, tick: &LockStepTick) -> Result<(), TransportError> {
        self.ticks
            .send_copy(*tick)
            .map_err(|e| TransportError::ipc("cannot publish a tick", e))?;
        self.tick_events
            .notify()
            .map_err(|e| TransportError::ipc("cannot signal a tick", e))?;
        Ok(())
    }

    fn answer(
        &mut self,
        tick: &LockStepTick,
        timeout: Duration,
    ) -> Result<Option<MotionCommand>, TransportError> {
        if let Some(command) = self.receive_answer(tick)? {
            return Ok(Some(command));
        }
        wait_for_event(
            &self.command_events,
            timeout,
            "waiting for a command failed",
        )?;
        self.receive_answer(tick)
    }

    fn next_command(&mut self, timeout: Duration) -> Result<Option<MotionCommand>, TransportError> {
        if let Some(command) = self.receive_command()? {
            return Ok(Some(command));
        }
        wait_for_event(
            &self.command_events,
            timeout,
            "waiting for a command failed",
        )?;
        self.receive_command()
    }
}

/// Watches the commands without taking part: what a logger or a test sees of the motion
/// module's input.
#[derive(Debug)]
pub struct CommandMonitor {
    node: Node<Ipc>,
    commands: Subscriber<Ipc, MotionCommand, ()>,
}

impl CommandMonitor {
    pub fn open(domain: &Domain, node_name: &str) -> Result<Self, TransportError> {
        let (node, _) = domain.create_node(node_name)?;
        let service = open_pubsub::<MotionCommand>(&node, COMMAND_SERVICE, &COMMAND_QOS)?;
        Ok(Self {
            commands: subscriber(&service, COMMAND_SERVICE)?,
            node,
        })
    }

    /// The next command in order, if one is waiting.
    pub fn try_next(&mut self) -> Result<Option<MotionCommand>, TransportError> {
        match self.commands.receive() {
            Ok(sample) => Ok(sample.map(|s| *s)),
            Err(e) => Err(TransportError::ipc("receive failed", e)),
        }
    }

    pub fn node(&self) -> &Node<Ipc> {
        &self.node
    }
}

fn send_frame<T: core::fmt::Debug + ZeroCopySend>(
    publisher: &Publisher<Ipc, T, ()>,
    frame: &T,
) -> Result<(), TransportError> {
    let mut sample = publisher
        .loan_uninit()
        .map_err(|e| TransportError::ipc("cannot loan a frame", e))?;
    // SAFETY: the copy writes a whole, valid `T` into the loaned payload, which is then
    // initialised; source and destination cannot overlap (ours vs shared memory).
    #[allow(unsafe_code)]
    let sample = unsafe {
        core::ptr::copy_nonoverlapping(frame, sample.payload_mut().as_mut_ptr(), 1);
        sample.assume_init()
    };
    sample
        .send()
        .map_err(|e| TransportError::ipc("cannot publish a frame", e))?;
    Ok(())
}
