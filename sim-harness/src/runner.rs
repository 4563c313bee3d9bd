//! Runs the paper's episodes in lock-step: physics, cameras, the controller's tick, the
//! walk. A driver is the expert (with ground truth), any `Policy`, or a controller behind a
//! [`ControllerLink`] (another process over iceoryx2, or a thread). All go through the
//! controller's own `ControlLoop`, so a command is computed exactly when the robot would
//! compute one (both cameras new) and repeated otherwise, from thumbnails made by the
//! robot's own code.
//!
//! A linked controller can also be followed by the expert ([`ExpertLabels`]): the learned
//! policy drives, and every state it computes a command in is recorded with the expert's
//! command for that state (DAgger's labels).

use std::cell::RefCell;
use std::rc::Rc;
use std::time::Instant;

use dribble_controller::tick_stats::TickStats;
use dribble_controller::{
    BottomFrame, CameraInput, CameraPosition, Clock, ControlLoop, LoopConfig, ManualClock, Policy,
    PolicyError, PolicyInput, PolicyOutput, TopFrame,
};
use glam::Vec2;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use dribble_controller::thumbnail::downscale;
use dribble_controller::transport::LockStepTick;
use dribble_controller::{BottomThumbnail, MotionCommand, SpeedCommand, TopThumbnail};

use crate::camera_geometry::CameraGeometry;
use crate::controller_link::{ControllerLink, LinkError};
use crate::dataset::{EpisodeRecording, Outcome, PolicyCommand, Row};
use crate::episode::EpisodeSetup;
use crate::episode_observer::{EpisodeObserver, NoObserver};
use crate::expert::{Expert, GroundTruth, Phase};
use crate::field::FieldGeometry;
use crate::render::{CleanTwin, Multisampling, RenderError, Renderer};
use crate::simulation::{STEPS_PER_MOTION_CYCLE, Simulation};
use crate::visibility::Visibility;
use crate::walk::WalkConfig;
use crate::world::{STEPS_PER_SECOND, WorldConfig};

/// How episodes are run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeConfig {
    pub time_limit_s: f32,
    pub world: WorldConfig,
    pub walk: WalkConfig,
    pub cameras: CameraGeometry,
    pub control: LoopConfig,
    /// Samples a pixel of the cameras' images (four: every shipped result's frames).
    pub multisampling: Multisampling,
}

impl Default for EpisodeConfig {
    fn default() -> Self {
        Self {
            time_limit_s: 90.0,
            world: WorldConfig::default(),
            walk: WalkConfig::default(),
            cameras: CameraGeometry::nao(),
            control: LoopConfig::default(),
            multisampling: Multisampling::Four,
        }
    }
}

impl EpisodeConfig {
    /// A renderer of these episodes' two cameras on the SPL field.
    pub fn renderer(&self) -> Result<Renderer, RenderError> {
        Renderer::with_multisampling(
            &FieldGeometry::SPL,
            self.world.goal_depth,
            &self.cameras,
            self.multisampling,
        )
    }
}

/// What an episode did.
#[derive(Clone, Debug)]
pub struct EpisodeResult {
    pub setup: EpisodeSetup,
    pub outcome: Outcome,
    /// Simulated seconds until the end.
    pub duration_s: f32,
    pub distance_walked_m: f32,
    /// Robot and ball positions, ten times a second.
    pub robot_path: Vec<Vec2>,
    pub ball_path: Vec<Vec2>,
    /// The robot's heading (radians, field frame) at the same instants as `robot_path`.
    pub heading_path: Vec<f32>,
    /// When the ball's centre was first inside either camera's image (checked ten times a
    /// second, from the poses alone); `None` if it never was.
    pub first_sighting_s: Option<f32>,
    /// Commands computed from new camera pairs.
    pub computed_commands: u64,
    /// Wall-clock time of each controller tick that computed a command; for a linked
    /// controller, of the whole lock-step round trip (tick out, command back).
    pub tick_times: TickStats,
    /// Why the episode failed, when the outcome is [`Outcome::ControllerLost`].
    pub failure: Option<String>,
    /// Commands of a labelled episode that the expert's command replaced (β's draws).
    pub expert_executed: u64,
}

/// Shares the truth with the expert inside the control loop, and its phase back.
#[derive(Debug)]
struct ExpertChannel {
    truth: GroundTruth,
    phase: Phase,
}

/// The expert as a `Policy`: it ignores the thumbnails and reads the truth the runner
/// hands it before every tick.
#[derive(Debug)]
struct ExpertPolicy {
    expert: Expert,
    channel: Rc<RefCell<ExpertChannel>>,
}

impl Policy for ExpertPolicy {
    fn step(&mut self, _: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        let mut channel = self.channel.borrow_mut();
        let (command, phase) = self.expert.decide(&channel.truth);
        channel.phase = phase;
        let [forward, left, turn] = command.as_array();
        Ok(PolicyOutput {
            forward,
            left,
            turn,
        })
    }

    fn reset(&mut self) {
        self.expert.reset();
    }
}

/// Who drives the robot.
// One per episode, on the stack of the runner: the expert's ball memory makes its variant
// larger than the others, which costs nothing here.
#[allow(clippy::large_enum_variant)]
pub enum Driver<'a> {
    /// The scripted expert; it needs no images, but can be given them to record.
    Expert(Expert),
    /// A policy that sees the rendered thumbnails.
    Policy(&'a mut dyn Policy),
    /// A controller of its own (a process or a thread) that gets the rendered frames and
    /// a tick per motion cycle, and answers with commands.
    Controller(&'a mut dyn ControllerLink),
    /// A controller as above, followed by the expert: each computed command's state is
    /// labelled with the expert's command, which is executed instead with probability β.
    LabelledController(&'a mut dyn ControllerLink, Box<ExpertLabels>),
}

/// The expert following a learned policy (DAgger, Ross et al. 2011): it decides in every
/// state the policy computes a command in, exactly as it would when driving, and with
/// probability `beta` its command is the one executed (and held until the next computed
/// command). The draws come from a generator seeded by the episode, so an episode
/// replays the same.
#[derive(Clone, Debug)]
pub struct ExpertLabels {
    expert: Expert,
    beta: f64,
    draws: ChaCha8Rng,
}

impl ExpertLabels {
    /// Stream of the draws, apart from the episode placement's own stream.
    const DRAW_STREAM: u64 = 0xDA66_E500;

    /// `beta` is the probability, per computed command, that the expert's command is
    /// executed instead of the policy's; it is clamped to [0, 1].
    pub fn new(expert: Expert, beta: f64, episode_seed: u64) -> Self {
        let mut draws = ChaCha8Rng::seed_from_u64(episode_seed);
        draws.set_stream(Self::DRAW_STREAM);
        Self {
            expert,
            beta: if beta.is_nan() {
                0.0
            } else {
                beta.clamp(0.0, 1.0)
            },
            draws,
        }
    }

    pub fn beta(&self) -> f64 {
        self.beta
    }

    /// The expert's command and phase in `truth`, and whether it is the one executed.
    fn label(&mut self, truth: &GroundTruth) -> (SpeedCommand, Phase, bool) {
        let (command, phase) = self.expert.decide(truth);
        let executed = self.beta > 0.0 && self.draws.random_bool(self.beta);
        (command, phase, executed)
    }
}

impl std::fmt::Debug for Driver<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Expert(expert) => f.debug_tuple("Expert").field(expert).finish(),
            Self::Policy(_) => f.write_str("Policy"),
            Self::Controller(_) => f.write_str("Controller"),
            Self::LabelledController(_, labels) => {
                f.debug_tuple("LabelledController").field(labels).finish()
            }
        }
    }
}

/// Runs one episode. Images are rendered when a renderer is given (a policy needs one);
/// rows are recorded when a recording is given (for a linked controller, only when it is
/// labelled: the rows need the expert's commands).
pub fn run_episode(
    setup: &EpisodeSetup,
    config: &EpisodeConfig,
    driver: Driver<'_>,
    renderer: Option<&mut Renderer>,
    recording: Option<&mut EpisodeRecording>,
) -> Result<EpisodeResult, RenderError> {
    run_episode_observed(setup, config, driver, renderer, recording, &mut NoObserver)
}

/// [`run_episode`], showing `observer` every frame, command and state as it plays.
pub fn run_episode_observed(
    setup: &EpisodeSetup,
    config: &EpisodeConfig,
    driver: Driver<'_>,
    mut renderer: Option<&mut Renderer>,
    recording: Option<&mut EpisodeRecording>,
    observer: &mut dyn EpisodeObserver,
) -> Result<EpisodeResult, RenderError> {
    observer.start(setup);
    let look = setup.conditions.resolve(setup.seed);
    if let Some(renderer) = renderer.as_deref_mut() {
        renderer.begin_episode(&look);
    }
    let simulation = Simulation::new(setup, config.world, config.walk, config.cameras);
    match driver {
        Driver::Expert(mut expert) => {
            expert.see_among(&look);
            let channel = Rc::new(RefCell::new(ExpertChannel {
                truth: ground_truth(&simulation, setup),
                phase: Phase::Search,
            }));
            let policy = ExpertPolicy {
                expert,
                channel: Rc::clone(&channel),
            };
            let cycles = InProcess::new(config, Box::new(policy), Some(channel), recording);
            play(setup, config, simulation, cycles, renderer, observer)
        }
        Driver::Policy(policy) => {
            let cycles = InProcess::new(config, Box::new(policy), None, recording);
            play(setup, config, simulation, cycles, renderer, observer)
        }
        Driver::Controller(link) => {
            let cycles = Linked::new(config, link, None);
            play(setup, config, simulation, cycles, renderer, observer)
        }
        Driver::LabelledController(link, mut labels) => {
            labels.expert.see_among(&look);
            let labelling = Labelling {
                labels: *labels,
                recording,
                held: None,
                thumbnails: (
                    Box::new(TopThumbnail::black()),
                    Box::new(BottomThumbnail::black()),
                ),
            };
            let cycles = Linked::new(config, link, Some(labelling));
            play(setup, config, simulation, cycles, renderer, observer)
        }
    }
}

/// What the robot and the ball are at this instant, as the expert reads it.
fn ground_truth(simulation: &Simulation, setup: &EpisodeSetup) -> GroundTruth {
    GroundTruth {
        robot: simulation.world().robot_pose(),
        ball: simulation.world().ball().position.truncate(),
        target_side: setup.target_side,
        time_s: simulation.time().as_nanos() as f64 / 1e9,
    }
}

/// What a motion cycle gave: the controller's command, and what the walk executes (or why
/// the episode cannot go on).
struct Cycle {
    command: MotionCommand,
    execute: Result<SpeedCommand, String>,
}

/// What computes an episode's commands: the controller's loop in this process
/// ([`InProcess`]) or a controller behind a link ([`Linked`]). Both see every frame as a
/// camera takes it and answer every motion cycle.
trait MotionCycles {
    /// A camera took a frame; `top` and `bottom` hold the newest of each.
    fn frame(
        &mut self,
        camera: CameraPosition,
        top: &TopFrame,
        bottom: &BottomFrame,
    ) -> Result<(), String>;

    /// The motion cycle at the simulation's time: its command, or why none came. A row
    /// recorded now takes its clean twin's thumbnails from `clean_twin`, when there is one.
    fn cycle(
        &mut self,
        simulation: &Simulation,
        setup: &EpisodeSetup,
        frames: (&TopFrame, &BottomFrame),
        clean_twin: Option<&mut CleanTwin>,
    ) -> Result<Cycle, String>;

    /// Computed commands, their tick times and the commands the expert's replaced.
    fn finish(self) -> (u64, TickStats, u64);
}

/// The one episode loop: physics steps, frames as the cameras take them, a command every
/// motion cycle, until a goal, the ball out, the time limit or a lost controller.
fn play(
    setup: &EpisodeSetup,
    config: &EpisodeConfig,
    mut simulation: Simulation,
    mut cycles: impl MotionCycles,
    mut renderer: Option<&mut Renderer>,
    observer: &mut dyn EpisodeObserver,
) -> Result<EpisodeResult, RenderError> {
    let (mut top, mut bottom) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    let limit_steps = (config.time_limit_s * STEPS_PER_SECOND as f32).round() as u64;
    let mut trace = Trace::new(setup, config.cameras);
    let mut failure = None;
    let outcome = loop {
        let camera = simulation.step();
        if let Some(camera) = camera {
            take_frame(
                &simulation,
                camera,
                renderer.as_deref_mut(),
                &mut top,
                &mut bottom,
            )?;
            observer.frame(simulation.time(), camera, &top, &bottom);
        }
        trace.after_step(&simulation);
        let motion_cycle = simulation
            .world()
            .steps()
            .is_multiple_of(STEPS_PER_MOTION_CYCLE);
        if motion_cycle {
            observer.before_tick(
                simulation.time(),
                simulation.world().robot_pose(),
                simulation.world().ball().position.truncate(),
            );
        }
        if let Some(camera) = camera
            && let Err(error) = cycles.frame(camera, &top, &bottom)
        {
            failure = Some(error);
            break Outcome::ControllerLost;
        }
        if motion_cycle {
            let clean_twin = renderer.as_deref_mut().and_then(Renderer::clean_twin_mut);
            match cycles.cycle(&simulation, setup, (&top, &bottom), clean_twin) {
                Ok(Cycle { command, execute }) => {
                    observe_cycle(observer, &simulation, &command);
                    match execute {
                        Ok(speed) => simulation.set_command(speed),
                        Err(error) => {
                            failure = Some(error);
                            break Outcome::ControllerLost;
                        }
                    }
                }
                Err(error) => {
                    failure = Some(error);
                    break Outcome::ControllerLost;
                }
            }
        }
        if let Some(outcome) = episode_end(&simulation, setup, limit_steps, observer) {
            break outcome;
        }
    };
    observer.end(simulation.time(), outcome);
    let (computed_commands, tick_times, expert_executed) = cycles.finish();
    let end = Ending {
        outcome,
        computed_commands,
        tick_times,
        failure,
        expert_executed,
    };
    Ok(trace.finish(&simulation, setup, end))
}

/// The controller's loop in this process, on the simulation's clock, driving with the
/// expert or a policy; rows recorded when a recording is given.
struct InProcess<'p, 'r> {
    control: ControlLoop<Box<dyn Policy + 'p>, ManualClock>,
    clock: ManualClock,
    /// The expert's truth and phase, when the expert drives.
    expert: Option<Rc<RefCell<ExpertChannel>>>,
    recording: Option<&'r mut EpisodeRecording>,
    new_frames: (bool, bool),
    tick_times: TickStats,
}

impl<'p, 'r> InProcess<'p, 'r> {
    fn new(
        config: &EpisodeConfig,
        policy: Box<dyn Policy + 'p>,
        expert: Option<Rc<RefCell<ExpertChannel>>>,
        recording: Option<&'r mut EpisodeRecording>,
    ) -> Self {
        let clock = ManualClock::default();
        let mut control = ControlLoop::new(config.control, policy, clock.clone());
        control.reset_episode();
        Self {
            control,
            clock,
            expert,
            recording,
            new_frames: (false, false),
            tick_times: TickStats::new(config.control.budget),
        }
    }
}

impl MotionCycles for InProcess<'_, '_> {
    fn frame(
        &mut self,
        camera: CameraPosition,
        _: &TopFrame,
        _: &BottomFrame,
    ) -> Result<(), String> {
        match camera {
            CameraPosition::Top => self.new_frames.0 = true,
            CameraPosition::Bottom => self.new_frames.1 = true,
        }
        Ok(())
    }

    fn cycle(
        &mut self,
        simulation: &Simulation,
        setup: &EpisodeSetup,
        (top, bottom): (&TopFrame, &BottomFrame),
        clean_twin: Option<&mut CleanTwin>,
    ) -> Result<Cycle, String> {
        self.clock.set(simulation.time());
        let truth = ground_truth(simulation, setup);
        if let Some(expert) = &self.expert {
            expert.borrow_mut().truth = truth;
        }
        let input = CameraInput {
            top: self.new_frames.0.then_some(top),
            bottom: self.new_frames.1.then_some(bottom),
        };
        self.new_frames = (false, false);
        let started = Instant::now();
        let command = self.control.tick(input);
        let elapsed = started.elapsed();
        if command.is_new() {
            self.tick_times.record(elapsed);
            if let Some(recording) = self.recording.as_deref_mut() {
                let (top_thumbnail, bottom_thumbnail) = self.control.thumbnails();
                recording.push(Row {
                    top: top_thumbnail,
                    bottom: bottom_thumbnail,
                    command: command.speed,
                    robot: truth.robot,
                    ball: truth.ball,
                    time_s: self.control.clock().now().as_nanos() as f64 / 1e9,
                    phase: self
                        .expert
                        .as_ref()
                        .map_or(Phase::Search, |expert| expert.borrow().phase),
                    policy_command: None,
                    clean_twin: twin_thumbnails(clean_twin, (top_thumbnail, bottom_thumbnail)),
                });
            }
        }
        Ok(Cycle {
            command,
            execute: Ok(command.speed),
        })
    }

    fn finish(self) -> (u64, TickStats, u64) {
        (self.control.counters().new_commands, self.tick_times, 0)
    }
}

/// A controller behind a link: frames go out as the cameras take them, a tick every motion
/// cycle, its command back; followed by the expert when labelled.
struct Linked<'l, 'r> {
    link: &'l mut dyn ControllerLink,
    labelling: Option<Labelling<'r>>,
    index: u64,
    computed_commands: u64,
    expert_executed: u64,
    tick_times: TickStats,
}

impl<'l, 'r> Linked<'l, 'r> {
    fn new(
        config: &EpisodeConfig,
        link: &'l mut dyn ControllerLink,
        labelling: Option<Labelling<'r>>,
    ) -> Self {
        Self {
            link,
            labelling,
            index: 0,
            computed_commands: 0,
            expert_executed: 0,
            tick_times: TickStats::new(config.control.budget),
        }
    }
}

impl MotionCycles for Linked<'_, '_> {
    fn frame(
        &mut self,
        camera: CameraPosition,
        top: &TopFrame,
        bottom: &BottomFrame,
    ) -> Result<(), String> {
        match camera {
            CameraPosition::Top => self.link.publish_top(top),
            CameraPosition::Bottom => self.link.publish_bottom(bottom),
        }
        .map_err(|error: LinkError| error.to_string())
    }

    fn cycle(
        &mut self,
        simulation: &Simulation,
        setup: &EpisodeSetup,
        frames: (&TopFrame, &BottomFrame),
        clean_twin: Option<&mut CleanTwin>,
    ) -> Result<Cycle, String> {
        let tick = LockStepTick {
            episode: setup.seed,
            index: self.index,
            time_ns: simulation.time().as_nanos(),
        };
        self.index += 1;
        let started = Instant::now();
        let command = self
            .link
            .exchange(&tick)
            .map_err(|error| error.to_string())?;
        if command.is_new() {
            self.tick_times.record(started.elapsed());
            self.computed_commands += 1;
        }
        let execute = match self.labelling.as_mut() {
            None => Ok(command.speed),
            Some(labelling) => {
                let truth = ground_truth(simulation, setup);
                labelling
                    .follow(&command, truth, truth.time_s, frames, clean_twin)
                    .map(|(speed, executed)| {
                        self.expert_executed += u64::from(executed);
                        speed
                    })
            }
        };
        Ok(Cycle { command, execute })
    }

    fn finish(self) -> (u64, TickStats, u64) {
        (
            self.computed_commands,
            self.tick_times,
            self.expert_executed,
        )
    }
}

/// A row's clean-twin thumbnails, when the renderer has a twin: the twin's, or the row's
/// `own` where the episode is its own twin.
fn twin_thumbnails<'a>(
    twin: Option<&'a mut CleanTwin>,
    own: (&'a TopThumbnail, &'a BottomThumbnail),
) -> Option<(&'a TopThumbnail, &'a BottomThumbnail)> {
    twin.map(|twin| twin.thumbnails().unwrap_or(own))
}

/// Shows `observer` a motion cycle: the command the motion module got, and the state.
fn observe_cycle(
    observer: &mut dyn EpisodeObserver,
    simulation: &Simulation,
    command: &MotionCommand,
) {
    let time = simulation.time();
    observer.command(time, command);
    observer.state(
        time,
        simulation.world().robot_pose(),
        simulation.world().ball().position.truncate(),
    );
}

/// Takes the frame of `camera` that is due now: rendered if there is a renderer, stamped
/// with its sequence number and time in any case.
fn take_frame(
    simulation: &Simulation,
    camera: CameraPosition,
    mut renderer: Option<&mut Renderer>,
    top: &mut TopFrame,
    bottom: &mut BottomFrame,
) -> Result<(), RenderError> {
    let (sequence, time) = (simulation.frame_sequence(camera), simulation.time());
    let model = simulation.camera(camera);
    let scene = simulation.scene();
    match camera {
        CameraPosition::Top => {
            if let Some(renderer) = renderer.as_deref_mut() {
                renderer.render(camera, &model, &scene, top)?;
            }
            top.restamp(sequence, time);
        }
        CameraPosition::Bottom => {
            if let Some(renderer) = renderer.as_deref_mut() {
                renderer.render(camera, &model, &scene, bottom)?;
            }
            bottom.restamp(sequence, time);
        }
    }
    if let Some(twin) = renderer.and_then(Renderer::clean_twin_mut) {
        twin.render(camera, &model, &scene)?;
    }
    Ok(())
}

/// How the episode ends at this step, if it does (`observer` may abandon it).
fn episode_end(
    simulation: &Simulation,
    setup: &EpisodeSetup,
    limit_steps: u64,
    observer: &mut dyn EpisodeObserver,
) -> Option<Outcome> {
    if simulation
        .world()
        .steps()
        .is_multiple_of(STEPS_PER_MOTION_CYCLE)
        && observer.abandon()
    {
        return Some(Outcome::Abandoned);
    }
    let field = simulation.world().field();
    let ball = simulation.world().ball().position;
    if field.is_goal(setup.target_side, ball.x, ball.y) {
        Some(Outcome::Goal)
    } else if field.is_out(ball.x, ball.y) {
        Some(Outcome::BallOut)
    } else if simulation.world().steps() >= limit_steps {
        Some(Outcome::TimeLimit)
    } else {
        None
    }
}

/// How an episode ended, and what was counted on the way.
struct Ending {
    outcome: Outcome,
    computed_commands: u64,
    tick_times: TickStats,
    failure: Option<String>,
    expert_executed: u64,
}

/// The robot's and the ball's paths, the heading, the distance walked and the first sighting
/// of the ball, step by step.
struct Trace {
    robot_path: Vec<Vec2>,
    ball_path: Vec<Vec2>,
    heading_path: Vec<f32>,
    first_sighting_s: Option<f32>,
    cameras: CameraGeometry,
    target_side: f32,
    distance: f32,
    last_position: Vec2,
}

impl Trace {
    fn new(setup: &EpisodeSetup, cameras: CameraGeometry) -> Self {
        Self {
            robot_path: Vec::new(),
            ball_path: Vec::new(),
            heading_path: Vec::new(),
            first_sighting_s: None,
            cameras,
            target_side: setup.target_side,
            distance: 0.0,
            last_position: Vec2::new(setup.robot.x, setup.robot.y),
        }
    }

    /// Samples the paths at this instant (and looks for the ball until it is first seen).
    fn sample(&mut self, simulation: &Simulation) {
        let world = simulation.world();
        let pose = world.robot_pose();
        let ball = world.ball().position.truncate();
        self.robot_path.push(Vec2::new(pose.x, pose.y));
        self.ball_path.push(ball);
        self.heading_path.push(pose.theta);
        if self.first_sighting_s.is_none()
            && Visibility::of(&self.cameras, world.field(), pose, ball, self.target_side)
                .ball_in_either()
        {
            self.first_sighting_s = Some(simulation.time().as_nanos() as f32 / 1e9);
        }
    }

    fn after_step(&mut self, simulation: &Simulation) {
        let pose = simulation.world().robot_pose();
        let position = Vec2::new(pose.x, pose.y);
        self.distance += (position - self.last_position).length();
        self.last_position = position;
        if simulation
            .world()
            .steps()
            .is_multiple_of(STEPS_PER_SECOND / 10)
        {
            self.sample(simulation);
        }
    }

    fn finish(
        mut self,
        simulation: &Simulation,
        setup: &EpisodeSetup,
        end: Ending,
    ) -> EpisodeResult {
        let Ending {
            outcome,
            computed_commands,
            tick_times,
            failure,
            expert_executed,
        } = end;
        self.sample(simulation);
        EpisodeResult {
            setup: *setup,
            outcome,
            duration_s: simulation.time().as_nanos() as f32 / 1e9,
            distance_walked_m: self.distance,
            robot_path: self.robot_path,
            ball_path: self.ball_path,
            heading_path: self.heading_path,
            first_sighting_s: self.first_sighting_s,
            computed_commands,
            tick_times,
            failure,
            expert_executed,
        }
    }
}

/// A labelled episode's state beside the link: the expert, the rows, the expert command
/// being executed, the thumbnails made from the frames the controller computed from.
struct Labelling<'r> {
    labels: ExpertLabels,
    recording: Option<&'r mut EpisodeRecording>,
    /// The expert's command while it is the executed one (until the next computed command).
    held: Option<SpeedCommand>,
    thumbnails: (Box<TopThumbnail>, Box<BottomThumbnail>),
}

impl Labelling<'_> {
    /// The command to execute for the controller's `command`, with the state labelled.
    /// Thumbnails are made by the robot's own code from the frames the command names;
    /// a command computed from other frames than the newest ones is an error (the
    /// lock-step would have been broken), since the row would not show what the policy saw.
    fn follow(
        &mut self,
        command: &MotionCommand,
        truth: GroundTruth,
        time_s: f64,
        frames: (&TopFrame, &BottomFrame),
        clean_twin: Option<&mut CleanTwin>,
    ) -> Result<(SpeedCommand, bool), String> {
        if !command.is_new() {
            // A repeat holds what was executed; a stop (cameras silent) stops.
            return Ok(match self.held {
                Some(speed) if !command.is_stop() => (speed, false),
                _ => (command.speed, false),
            });
        }
        let (top, bottom) = frames;
        let (top_sequence, bottom_sequence) = (top.header().sequence, bottom.header().sequence);
        if (command.top_sequence, command.bottom_sequence) != (top_sequence, bottom_sequence) {
            return Err(format!(
                "the controller computed from frames {}/{} but the newest are {top_sequence}/{bottom_sequence}: \
                 the row would not show what it saw",
                command.top_sequence, command.bottom_sequence
            ));
        }
        let (expert, phase, executed) = self.labels.label(&truth);
        self.held = executed.then_some(expert);
        if let Some(recording) = self.recording.as_deref_mut() {
            let (top_thumbnail, bottom_thumbnail) = &mut self.thumbnails;
            downscale(top, top_thumbnail);
            downscale(bottom, bottom_thumbnail);
            let (top_thumbnail, bottom_thumbnail) = (&**top_thumbnail, &**bottom_thumbnail);
            recording.push(Row {
                top: top_thumbnail,
                bottom: bottom_thumbnail,
                command: expert,
                robot: truth.robot,
                ball: truth.ball,
                time_s,
                phase,
                policy_command: Some(PolicyCommand {
                    speed: command.speed,
                    expert_executed: executed,
                }),
                clean_twin: twin_thumbnails(clean_twin, (top_thumbnail, bottom_thumbnail)),
            });
        }
        Ok((if executed { expert } else { command.speed }, executed))
    }
}
