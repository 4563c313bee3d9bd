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
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
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

/// `ZeroCopySend` for the messages, each named `dribble::<Type>` across processes (a
/// subscriber of another layout is refused by that name).
macro_rules! zero_copy_send {
    ($($message:ident),*) => {$(
        // SAFETY: `#[repr(C)]` structs of integers, floats and byte arrays, without pointers,
        // references or handles; their layouts are fixed by tests on every target.
        #[allow(unsafe_code)]
        unsafe impl ZeroCopySend for $message {
            unsafe fn type_name() -> &'static str {
                concat!("dribble::", stringify!($message))
            }
        }
    )*};
}

zero_copy_send!(
    FrameHeader,
    TopFrame,
    BottomFrame,
    MotionCommand,
    LockStepTick
);

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

    /// What [`Domain::label`] calls the default domain; as a name it also means that one.
    pub const DEFAULT_LABEL: &str = "default";

    /// The default domain (`None`, or the name `default`) or a named one: letters, digits,
    /// `-` and `_`, at most 32.
    pub fn new(name: Option<&str>) -> Result<Self, TransportError> {
        // "default" is how the default domain is printed; whoever passes it back (a script
        // copying a log line, a parent starting a child) means that domain, not a new one.
        let name = name.filter(|n| *n != Self::DEFAULT_LABEL);
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

    /// The domain's name; `None` for iceoryx2's default configuration. Pass this on to a
    /// child process (as `--domain`) only when it is `Some`.
    pub fn name(&self) -> Option<&str> {
        self.name.as_deref()
    }

    /// The name for people and logs: the name, or `default`.
    pub fn label(&self) -> &str {
        self.name.as_deref().unwrap_or(Self::DEFAULT_LABEL)
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

fn open_event(node: &Node<Ipc>, name: &'static str) -> Result<EventFactory<Ipc>, TransportError> {
    let service_name =
        ServiceName::new(name).map_err(|e| TransportError::ipc("invalid service name", e))?;
    node.service_builder(&service_name)
        .event()
        .max_notifiers(4)
        .max_listeners(4)
        .open_or_create()
        .map_err(|e| TransportError::ipc(name, e))
}

/// What creating a port of the service `name` gave, its error as a [`TransportError`].
fn created<T, E: core::fmt::Debug>(
    port: Result<T, E>,
    name: &'static str,
) -> Result<T, TransportError> {
    port.map_err(|e| TransportError::ipc(name, e))
}

fn subscriber<T: core::fmt::Debug + ZeroCopySend + 'static>(
    factory: &PubSubFactory<Ipc, T, ()>,
    name: &'static str,
) -> Result<Subscriber<Ipc, T, ()>, TransportError> {
    created(factory.subscriber_builder().create(), name)
}

fn listener(
    factory: &EventFactory<Ipc>,
    name: &'static str,
) -> Result<Listener<Ipc>, TransportError> {
    created(factory.listener_builder().create(), name)
}

fn notifier(
    factory: &EventFactory<Ipc>,
    name: &'static str,
) -> Result<Notifier<Ipc>, TransportError> {
    created(factory.notifier_builder().create(), name)
}

/// A publisher on `name` for a process in `role` ("simulator" or "controller"), which says
/// so when the service's publishers are taken.
fn publisher<T: core::fmt::Debug + ZeroCopySend + 'static>(
    factory: &PubSubFactory<Ipc, T, ()>,
    name: &'static str,
    role: &'static str,
) -> Result<Publisher<Ipc, T, ()>, TransportError> {
    factory
        .publisher_builder()
        .max_loaned_samples(1)
        .create()
        .map_err(|e| match e {
            PublisherCreateError::ExceedsMaxSupportedPublishers => TransportError::DomainBusy {
                service: name,
                role,
            },
            e => TransportError::ipc(name, e),
        })
}

/// Every service of a domain, opened by one node with the settings both sides share.
#[derive(Debug)]
struct Services {
    /// Held, never used: while it lives, this process is alive in the domain.
    _node: Node<Ipc>,
    cleaned_dead_nodes: u64,
    top: PubSubFactory<Ipc, TopFrame, ()>,
    bottom: PubSubFactory<Ipc, BottomFrame, ()>,
    ticks: PubSubFactory<Ipc, LockStepTick, ()>,
    commands: PubSubFactory<Ipc, MotionCommand, ()>,
    tick_events: EventFactory<Ipc>,
    command_events: EventFactory<Ipc>,
}

impl Services {
    fn open(domain: &Domain, node_name: &str) -> Result<Self, TransportError> {
        let (node, cleaned_dead_nodes) = domain.create_node(node_name)?;
        Ok(Self {
            top: open_pubsub(&node, TOP_CAMERA_SERVICE, &FRAME_QOS)?,
            bottom: open_pubsub(&node, BOTTOM_CAMERA_SERVICE, &FRAME_QOS)?,
            ticks: open_pubsub(&node, TICK_SERVICE, &TICK_QOS)?,
            commands: open_pubsub(&node, COMMAND_SERVICE, &COMMAND_QOS)?,
            tick_events: open_event(&node, TICK_SERVICE)?,
            command_events: open_event(&node, COMMAND_SERVICE)?,
            _node: node,
            cleaned_dead_nodes,
        })
    }
}

/// A lock-step service's sending end: its publisher and the notifier of its event service,
/// which wakes the other side.
#[derive(Debug)]
struct SignallingPublisher<T: core::fmt::Debug + ZeroCopySend + 'static> {
    publisher: Publisher<Ipc, T, ()>,
    notifier: Notifier<Ipc>,
}

impl<T: core::fmt::Debug + Copy + ZeroCopySend + 'static> SignallingPublisher<T> {
    /// Sends a copy of `value` and wakes the listeners (`what` names the send in an error).
    fn send(&self, value: T, what: &'static str) -> Result<(), TransportError> {
        self.publisher
            .send_copy(value)
            .map_err(|e| TransportError::ipc(what, e))?;
        self.notifier
            .notify()
            .map_err(|e| TransportError::ipc(what, e))?;
        Ok(())
    }
}

/// A lock-step service's receiving end: its subscriber and the listener its publisher's
/// notifier wakes.
#[derive(Debug)]
struct SignalledSubscriber<T: core::fmt::Debug + ZeroCopySend + 'static> {
    subscriber: Subscriber<Ipc, T, ()>,
    listener: Listener<Ipc>,
}

impl<T: core::fmt::Debug + Copy + ZeroCopySend + 'static> SignalledSubscriber<T> {
    /// The next message, waiting at most `timeout` for a signal when none is there.
    fn next_or_wait(
        &self,
        timeout: Duration,
        what: &'static str,
    ) -> Result<Option<T>, TransportError> {
        next_or_wait(&self.subscriber, &self.listener, timeout, what)
    }
}

/// The next message in order, copied out, if one is waiting.
fn next_message<T: core::fmt::Debug + Copy + ZeroCopySend>(
    subscriber: &Subscriber<Ipc, T, ()>,
) -> Result<Option<T>, TransportError> {
    match subscriber.receive() {
        Ok(sample) => Ok(sample.map(|s| *s)),
        Err(e) => Err(TransportError::ipc("receive failed", e)),
    }
}

/// The next message on `subscriber`, waiting at most `timeout` for `events` to signal one
/// when none is there (`what` names the wait in an error).
fn next_or_wait<T: core::fmt::Debug + Copy + ZeroCopySend>(
    subscriber: &Subscriber<Ipc, T, ()>,
    events: &Listener<Ipc>,
    timeout: Duration,
    what: &'static str,
) -> Result<Option<T>, TransportError> {
    if let Some(message) = next_message(subscriber)? {
        return Ok(Some(message));
    }
    wait_for_event(events, timeout, what)?;
    next_message(subscriber)
}

/// Sleeps until the other side signals, at most `timeout`. A signal (SIGINT, SIGTERM)
/// only cuts the wait short: the caller's loop looks at its stop flag next.
///
/// The wait is a `ppoll` on the listener's socket, not iceoryx2's `timed_wait`: that one
/// sets `SO_RCVTIMEO`, which the kernel counts in scheduler ticks, so on a kernel with
/// `HZ=250` a 10 ms timeout lasts 12 to 16 ms and the lock-step watchdog published its stops
/// every 16 ms instead of every 10 ms tick. `ppoll` sleeps on a high-resolution timer. The
/// notifications that woke it are then taken without blocking.
fn wait_for_event(
    listener: &Listener<Ipc>,
    timeout: Duration,
    what: &'static str,
) -> Result<(), TransportError> {
    if poll_readable(listener, timeout).map_err(|e| TransportError::ipc(what, e))? {
        listener
            .try_wait(|_| {})
            .map_err(|e| TransportError::ipc(what, e))?;
    }
    Ok(())
}

/// Whether the listener's socket became readable within `timeout`; an interrupting signal
/// counts as not readable.
#[allow(unsafe_code)]
fn poll_readable(listener: &Listener<Ipc>, timeout: Duration) -> std::io::Result<bool> {
    // SAFETY: the descriptor belongs to `listener`, which outlives this call; it is only
    // polled, never closed or read here.
    let fd = unsafe { listener.file_descriptor().native_handle() };
    let mut poll = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    let timeout = libc::timespec {
        tv_sec: libc::time_t::try_from(timeout.as_secs()).unwrap_or(libc::time_t::MAX),
        // Below 1e9, so it fits every platform's c_long.
        tv_nsec: timeout.subsec_nanos() as libc::c_long,
    };
    // SAFETY: one valid pollfd, a valid timespec and no signal mask, as ppoll(2) asks.
    let ready = unsafe { libc::ppoll(&mut poll, 1, &timeout, core::ptr::null()) };
    if ready < 0 {
        let error = std::io::Error::last_os_error();
        return match error.kind() {
            std::io::ErrorKind::Interrupted => Ok(false),
            _ => Err(error),
        };
    }
    Ok(ready > 0)
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
    /// Held, never used: while it lives, the controller is alive in the domain.
    _node: Node<Ipc>,
    top: Subscriber<Ipc, TopFrame, ()>,
    bottom: Subscriber<Ipc, BottomFrame, ()>,
    ticks: SignalledSubscriber<LockStepTick>,
    commands: SignallingPublisher<MotionCommand>,
    cleaned_dead_nodes: u64,
}

impl Iceoryx2ControllerPorts {
    pub fn open(domain: &Domain) -> Result<Self, TransportError> {
        let services = Services::open(domain, CONTROLLER_NODE)?;
        let commands = SignallingPublisher {
            publisher: publisher(&services.commands, COMMAND_SERVICE, "controller")?,
            notifier: notifier(&services.command_events, COMMAND_SERVICE)?,
        };
        Ok(Self {
            top: subscriber(&services.top, TOP_CAMERA_SERVICE)?,
            bottom: subscriber(&services.bottom, BOTTOM_CAMERA_SERVICE)?,
            ticks: SignalledSubscriber {
                subscriber: subscriber(&services.ticks, TICK_SERVICE)?,
                listener: listener(&services.tick_events, TICK_SERVICE)?,
            },
            commands,
            _node: services._node,
            cleaned_dead_nodes: services.cleaned_dead_nodes,
        })
    }

    /// How many dead nodes (killed processes) this start cleaned up after.
    pub fn cleaned_dead_nodes(&self) -> u64 {
        self.cleaned_dead_nodes
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
        self.commands.send(*command, "cannot publish a command")
    }

    fn next_tick(&mut self, timeout: Duration) -> Result<Option<LockStepTick>, TransportError> {
        self.ticks
            .next_or_wait(timeout, "waiting for a tick failed")
    }
}

/// The simulator's (or camera driver's and motion module's) side over iceoryx2.
#[derive(Debug)]
pub struct Iceoryx2SimulatorPorts {
    services: Services,
    top: Publisher<Ipc, TopFrame, ()>,
    bottom: Publisher<Ipc, BottomFrame, ()>,
    ticks: SignallingPublisher<LockStepTick>,
    commands: SignalledSubscriber<MotionCommand>,
}

impl Iceoryx2SimulatorPorts {
    pub fn open(domain: &Domain, node_name: &str) -> Result<Self, TransportError> {
        let services = Services::open(domain, node_name)?;
        Ok(Self {
            top: publisher(&services.top, TOP_CAMERA_SERVICE, "simulator")?,
            bottom: publisher(&services.bottom, BOTTOM_CAMERA_SERVICE, "simulator")?,
            ticks: SignallingPublisher {
                publisher: publisher(&services.ticks, TICK_SERVICE, "simulator")?,
                notifier: notifier(&services.tick_events, TICK_SERVICE)?,
            },
            commands: SignalledSubscriber {
                subscriber: subscriber(&services.commands, COMMAND_SERVICE)?,
                listener: listener(&services.command_events, COMMAND_SERVICE)?,
            },
            services,
        })
    }

    /// How many dead nodes (killed processes) opening these ports cleaned up after.
    pub fn cleaned_dead_nodes(&self) -> u64 {
        self.services.cleaned_dead_nodes
    }

    /// Whether a controller has opened its ports: it subscribes to the cameras and ticks and
    /// publishes commands. Samples sent before that are lost, so a lock-step simulator waits.
    pub fn controller_connected(&self) -> bool {
        let services = &self.services;
        services.commands.dynamic_config().number_of_publishers() > 0
            && services.ticks.dynamic_config().number_of_subscribers() > 0
            && services.top.dynamic_config().number_of_subscribers() > 0
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
        self.commands
            .listener
            .try_wait(|_| {})
            .map_err(|e| TransportError::ipc("cannot read command events", e))?;
        while newest(&self.commands.subscriber)?.is_some() {}
        Ok(())
    }

    fn publish_tick(&mut self, tick: &LockStepTick) -> Result<(), TransportError> {
        self.ticks.send(*tick, "cannot publish a tick")
    }

    fn next_command(&mut self, timeout: Duration) -> Result<Option<MotionCommand>, TransportError> {
        self.commands
            .next_or_wait(timeout, "waiting for a command failed")?
            .map(checked_command)
            .transpose()
    }
}

/// Watches the commands without taking part: what a logger or a test sees of the motion
/// module's input.
#[derive(Debug)]
pub struct CommandMonitor {
    /// Held, never used: while it lives, the monitor is alive in the domain.
    _node: Node<Ipc>,
    commands: SignalledSubscriber<MotionCommand>,
}

impl CommandMonitor {
    pub fn open(domain: &Domain, node_name: &str) -> Result<Self, TransportError> {
        let (node, _) = domain.create_node(node_name)?;
        let service = open_pubsub::<MotionCommand>(&node, COMMAND_SERVICE, &COMMAND_QOS)?;
        let events = open_event(&node, COMMAND_SERVICE)?;
        Ok(Self {
            commands: SignalledSubscriber {
                subscriber: subscriber(&service, COMMAND_SERVICE)?,
                listener: listener(&events, COMMAND_SERVICE)?,
            },
            _node: node,
        })
    }

    /// The next command in order, if one is waiting.
    pub fn try_next(&mut self) -> Result<Option<MotionCommand>, TransportError> {
        next_message(&self.commands.subscriber)
    }

    /// The next command in order, waiting at most `timeout` for the controller to send one.
    pub fn next(&mut self, timeout: Duration) -> Result<Option<MotionCommand>, TransportError> {
        self.commands
            .next_or_wait(timeout, "waiting for a command failed")
    }
}

/// A command from shared memory, checked before it goes anywhere near a walk.
fn checked_command(command: MotionCommand) -> Result<MotionCommand, TransportError> {
    command
        .checked()
        .map_err(|_| TransportError::MalformedCommand {
            sequence: command.sequence,
            speed: format!("{:?}", command.speed.as_array()),
        })
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
