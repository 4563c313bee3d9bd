//! The controller as its own process over iceoryx2, against real processes that die.
//!
//! Every test uses an iceoryx2 domain of its own. The fault tests measure how fast a death
//! is noticed, so they run one at a time, not beside each other's rendering.

mod support;

use std::fs::File;
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use dribble_controller::transport::ipc::{CONTROLLER_NODE, CommandMonitor, Domain};
use dribble_sim::controller_link::{Iceoryx2Link, LinkTimeouts};
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::runner::{Driver, EpisodeConfig, run_episode};
use serde_json::Value;
use support::{controller_binary, domain_name, fixture_manifest, scratch, wait_for_text};

const START: Duration = Duration::from_secs(60);

/// Held by each test that measures reaction times, so that they run one at a time.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A child process that is killed if the test fails before it is stopped.
struct Guarded(Option<Child>);

impl Guarded {
    fn child(&mut self) -> &mut Child {
        self.0.as_mut().expect("still running")
    }

    fn take(mut self) -> Child {
        self.0.take().expect("still running")
    }
}

impl Drop for Guarded {
    fn drop(&mut self) {
        if let Some(mut child) = self.0.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// A `dribble-controller run --clock simulation` in `domain`, logging into `dir`.
fn start_controller(domain: &str, dir: &Path, name: &str, policy: Option<&Path>) -> Guarded {
    let log = dir.join(format!("{name}.log"));
    let mut command = Command::new(controller_binary());
    command
        .args(["run", "--clock", "simulation", "--domain", domain])
        .stdin(Stdio::null())
        .stdout(File::create(dir.join(format!("{name}.out"))).expect("stdout file"))
        .stderr(File::create(&log).expect("log file"));
    if let Some(policy) = policy {
        command.arg("--policy").arg(policy);
    }
    let child = Guarded(Some(command.spawn().expect("the controller starts")));
    wait_for_text(&log, "event=ready", START);
    child
}

fn signal(child: &Child, signal: libc::c_int) {
    let pid = libc::pid_t::try_from(child.id()).expect("a pid");
    // SAFETY: kill(2) on our own child with a valid signal.
    #[allow(unsafe_code)]
    let result = unsafe { libc::kill(pid, signal) };
    assert_eq!(result, 0, "signal {signal} to {pid}");
}

/// Stops `child` with `sig` and returns its exit status once it is gone.
fn stop_with(mut child: Child, sig: libc::c_int) -> std::process::ExitStatus {
    signal(&child, sig);
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            return status;
        }
        assert!(Instant::now() < deadline, "the controller did not stop");
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn dribble(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dribble"))
        .args(args)
        .output()
        .expect("dribble runs")
}

fn text(output: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

fn eval_trajectories(dir: &Path, name: &str, extra: &[&str]) -> (Value, String) {
    let json = dir.join(format!("{name}.json"));
    let plot = dir.join(format!("{name}.png"));
    let log = dir.join(format!("{name}-controller.log"));
    let policy = fixture_manifest("rcnn");
    let mut args = vec![
        "eval",
        "--driver",
        policy.to_str().expect("utf-8 path"),
        "--episodes",
        "10000..10003",
        "--time-limit",
        "4",
        "--trajectories",
        json.to_str().expect("utf-8 path"),
        "--plot",
        plot.to_str().expect("utf-8 path"),
        "--controller-log",
        log.to_str().expect("utf-8 path"),
    ];
    args.extend_from_slice(extra);
    let output = dribble(&args);
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    let value = serde_json::from_str(&std::fs::read_to_string(json).expect("trajectories"))
        .expect("valid JSON");
    (value, said)
}

#[test]
fn both_transports_give_identical_trajectories() {
    let _serial = one_at_a_time();
    let dir = scratch("transports");
    let domain = domain_name("identity");
    let controller = controller_binary();
    let (over_ipc, said) = eval_trajectories(
        &dir,
        "iceoryx2",
        &[
            "--transport",
            "iceoryx2",
            "--domain",
            &domain,
            "--controller",
            controller.to_str().expect("utf-8 path"),
        ],
    );
    assert!(said.contains("event=controller_started"), "{said}");
    assert!(said.contains("controller statistics"), "{said}");
    let (in_process, _) = eval_trajectories(&dir, "in-process", &["--transport", "in-process"]);
    assert_eq!(
        over_ipc, in_process,
        "the same seeds, the same trajectories"
    );

    // The comparison means something: the robot moved, and differently per seed.
    let episodes = over_ipc["episodes"].as_array().expect("episodes");
    assert_eq!(episodes.len(), 3);
    let robot = |episode: &Value| episode["robot"].as_array().expect("robot path").clone();
    for (i, episode) in episodes.iter().enumerate() {
        let path = robot(episode);
        assert!(path.len() > 30, "4 s at 10 Hz");
        assert_ne!(path.first(), path.last(), "episode {i}: the robot moved");
        assert!(episode["computed_commands"].as_u64() > Some(100));
    }
    assert_ne!(robot(&episodes[0]), robot(&episodes[1]));
}

#[test]
fn a_killed_controller_fails_the_episode_within_a_liveness_interval() {
    let _serial = one_at_a_time();
    let dir = scratch("killed-controller");
    let name = domain_name("killed");
    let domain = Domain::new(Some(&name)).expect("domain");
    let mut controller = start_controller(&name, &dir, "controller", None).take();
    let mut link = Iceoryx2Link::connect(&domain, None, LinkTimeouts::default()).expect("connects");
    assert!(!link.owns_controller());

    // Kill it (SIGKILL: no chance to clean up) while the episode runs.
    let (killed_tx, killed_rx) = mpsc::channel();
    let pid = controller.id();
    let killer = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(300));
        controller.kill().expect("kill");
        killed_tx.send(Instant::now()).expect("send");
        controller.wait().expect("reaped")
    });
    // A time limit no episode reaches before the kill, however busy the machine: on a loaded
    // CI machine the killer thread's 300 ms sleep has outlasted a 90 s episode without
    // rendering, and the episode ended by its time limit before the kill.
    let config = EpisodeConfig {
        time_limit_s: 3600.0,
        ..EpisodeConfig::default()
    };
    let setup = EpisodeSetup::from_seed(10001);
    let result = run_episode(&setup, &config, Driver::Controller(&mut link), None, None)
        .expect("no rendering error");
    let ended = Instant::now();
    let killed_at = killed_rx.recv().expect("killed");
    killer.join().expect("killer");
    let noticed = ended.saturating_duration_since(killed_at);
    println!("a killed controller (pid {pid}) was noticed {noticed:?} after the kill");
    assert_eq!(result.outcome, Outcome::ControllerLost);
    let failure = result.failure.expect("a reason");
    assert!(failure.contains("died"), "{failure}");
    // The link checks every 10 ms whether the controller lives (LinkTimeouts::liveness):
    // a kill is noticed within that interval plus the check, far inside the 2 s answer
    // timeout it would otherwise wait for.
    assert!(
        noticed < Duration::from_millis(40),
        "noticed after {noticed:?}"
    );
}

#[test]
fn a_dead_simulator_gets_stops_and_a_new_one_carries_on() {
    let _serial = one_at_a_time();
    let dir = scratch("dead-simulator");
    let name = domain_name("deadsim");
    let domain = Domain::new(Some(&name)).expect("domain");
    let controller = start_controller(&name, &dir, "controller", Some(&fixture_manifest("cnn")));
    let mut monitor = CommandMonitor::open(&domain, "test-monitor").expect("monitor");

    // A simulator process plays a long episode against the running controller...
    let policy = fixture_manifest("cnn");
    let plot = dir.join("first.png");
    let mut simulator = Guarded(Some(
        Command::new(env!("CARGO_BIN_EXE_dribble"))
            .args(["eval", "--domain", &name, "--episodes", "10000..10001"])
            .args(["--time-limit", "90", "--driver"])
            .arg(&policy)
            .arg("--plot")
            .arg(&plot)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("the simulator starts"),
    ));
    // ...until the controller computes from its frames; then it is killed. The monitor is
    // polled every millisecond throughout, so the wall time of the last answered tick is
    // known to about that.
    let deadline = Instant::now() + START;
    loop {
        if let Some(command) = monitor.try_next().expect("receive")
            && command.is_new()
        {
            break;
        }
        assert!(Instant::now() < deadline, "no command computed from frames");
        std::thread::sleep(Duration::from_millis(1));
    }
    let (watching, mut last_answer) = (Instant::now(), Instant::now());
    while watching.elapsed() < Duration::from_millis(200) {
        if monitor.try_next().expect("receive").is_some() {
            last_answer = Instant::now();
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    simulator.child().kill().expect("kill the simulator");
    let killed_at = Instant::now();
    simulator.child().wait().expect("reaped");
    let first_stop = loop {
        if let Some(command) = monitor.try_next().expect("receive") {
            if command.is_stop() {
                break command;
            }
            last_answer = Instant::now();
        }
        assert!(killed_at.elapsed() < Duration::from_secs(5), "no stop");
        std::thread::sleep(Duration::from_millis(1));
    };
    let silence = last_answer.elapsed();
    println!("first stop {silence:?} after the last answered tick (the limit is 100 ms)");
    assert!(!first_stop.is_new(), "{first_stop:?}");
    // DESIGN.md: a stop once input has been silent for 3 camera periods, 100 ms (checked every
    // 10 ms tick period); not before, and not much later. Measured here from the arrival of
    // the last answer, which on a loaded machine can come up to a tick period after its tick
    // (seen: 89.3 ms during the whole suite): the lower bound allows two periods of that.
    assert!(
        (Duration::from_millis(80)..Duration::from_millis(150)).contains(&silence),
        "stop after {silence:?} of silence"
    );
    // From then on a stop every tick period, and nothing else: the next 20 commands are stops
    // of consecutive sequence numbers (none left out) arriving a median 10 ms apart. Timed by
    // arrival here (polled every millisecond): with the simulator gone the controller's clock
    // (the simulator's) stands still, so every watchdog stop carries the same stamp.
    let mut stops = vec![(Instant::now(), first_stop)];
    let watched = Instant::now();
    while stops.len() < 21 && watched.elapsed() < Duration::from_secs(5) {
        if let Some(next) = monitor.try_next().expect("receive") {
            assert!(next.is_stop(), "only stops: {next:?}");
            stops.push((Instant::now(), next));
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(stops.len(), 21, "20 more stops in 5 s");
    let mut intervals_ms: Vec<f64> = stops
        .windows(2)
        .map(|pair| {
            let ((then, a), (now, b)) = (pair[0], pair[1]);
            assert_eq!(b.sequence, a.sequence + 1, "{a:?} then {b:?}");
            now.duration_since(then).as_secs_f64() * 1e3
        })
        .collect();
    intervals_ms.sort_by(f64::total_cmp);
    let median_ms = intervals_ms[intervals_ms.len() / 2];
    println!("20 more stops, consecutive sequence numbers, median {median_ms:.1} ms apart");
    // The watchdog waits one tick period for a tick, then publishes: 10 ms and a little.
    assert!(
        (8.0..=14.0).contains(&median_ms),
        "a stop every 10 ms tick: median {median_ms} ms ({intervals_ms:?})"
    );

    // A new simulator finds the controller waiting, and cleans up after the dead one.
    let output = dribble(&[
        "eval",
        "--domain",
        &name,
        "--episodes",
        "10002..10003",
        "--time-limit",
        "2",
        "--driver",
        policy.to_str().expect("utf-8 path"),
        "--plot",
        dir.join("second.png").to_str().expect("utf-8 path"),
    ]);
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    assert!(said.contains("event=controller_joined"), "{said}");
    assert!(
        said.contains("event=iceoryx2_cleaned dead_processes=1"),
        "{said}"
    );
    assert!(
        said.contains("time limit"),
        "the episode ran to its end: {said}"
    );

    let status = stop_with(controller.take(), libc::SIGTERM);
    assert!(status.success(), "a clean stop: {status}");
    let log = std::fs::read_to_string(dir.join("controller.log")).expect("log");
    assert!(log.contains("event=simulator_silent"), "{log}");
    assert!(log.contains("event=simulator_back"), "{log}");
    assert!(log.contains("event=stopped"), "{log}");
    let statistics = std::fs::read_to_string(dir.join("controller.out")).expect("stdout");
    assert!(statistics.contains("tick time: p50"), "{statistics}");
    assert!(statistics.contains("overruns"), "{statistics}");
}

#[test]
fn a_killed_controller_is_cleaned_up_at_the_next_start() {
    let _serial = one_at_a_time();
    let dir = scratch("cleanup");
    let name = domain_name("cleanup");
    let domain = Domain::new(Some(&name)).expect("domain");
    let mut first = start_controller(&name, &dir, "first", None);
    first.child().kill().expect("kill");
    first.child().wait().expect("reaped");
    let left = domain.nodes_named(CONTROLLER_NODE).expect("list");
    assert_eq!(
        left.len(),
        1,
        "the killed controller left its node: {left:?}"
    );
    assert!(!left[0].alive);

    let mut second = start_controller(&name, &dir, "second", None);
    let log = std::fs::read_to_string(dir.join("second.log")).expect("log");
    assert!(log.contains("cleaned_dead_nodes=1"), "{log}");
    let nodes = domain.nodes_named(CONTROLLER_NODE).expect("list");
    assert_eq!(nodes.len(), 1, "{nodes:?}");
    assert!(nodes[0].alive && nodes[0].pid == i32::try_from(second.child().id()).ok());

    // The new controller serves (its command port was free again).
    let mut link = Iceoryx2Link::connect(&domain, None, LinkTimeouts::default()).expect("connects");
    let config = EpisodeConfig {
        time_limit_s: 1.0,
        ..EpisodeConfig::default()
    };
    let result = run_episode(
        &EpisodeSetup::from_seed(10000),
        &config,
        Driver::Controller(&mut link),
        None,
        None,
    )
    .expect("runs");
    assert_eq!(result.outcome, Outcome::TimeLimit, "{:?}", result.failure);
    drop(link);

    // SIGINT stops it as cleanly as SIGTERM, with its statistics.
    let status = stop_with(second.take(), libc::SIGINT);
    assert!(status.success(), "{status}");
    let statistics = std::fs::read_to_string(dir.join("second.out")).expect("stdout");
    assert!(statistics.contains("ticks 100:"), "{statistics}");
    assert!(
        domain
            .nodes_named(CONTROLLER_NODE)
            .expect("list")
            .is_empty()
    );
}

/// `dribble eval` of the fixture CNN on `episodes` in domain `name`, starting its own
/// controller (log and plot in `dir`), its standard output and error piped.
fn spawn_eval(dir: &Path, name: &str, episodes: &str, time_limit: &str) -> Guarded {
    Guarded(Some(
        Command::new(env!("CARGO_BIN_EXE_dribble"))
            .args(["eval", "--domain", name, "--episodes", episodes])
            .args(["--time-limit", time_limit, "--driver"])
            .arg(fixture_manifest("cnn"))
            .arg("--controller")
            .arg(controller_binary())
            .arg("--controller-log")
            .arg(dir.join("controller.log"))
            .arg("--plot")
            .arg(dir.join("plot.png"))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("eval starts"),
    ))
}

/// The pid in eval's "event=controller_started binary=... pid=N ..." line.
fn started_pid(line: &str) -> libc::pid_t {
    line.split(" pid=")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|pid| pid.parse().ok())
        .unwrap_or_else(|| panic!("no pid in {line:?}"))
}

#[test]
fn eval_reports_a_lost_controller_and_starts_a_new_one() {
    let _serial = one_at_a_time();
    let dir = scratch("eval-restart");
    let name = domain_name("eval-restart");
    let mut eval = spawn_eval(&dir, &name, "10000..10002", "20");
    // Results come on stdout, log events on stderr: one channel of lines for both.
    let stdout = eval.child().stdout.take().expect("stdout");
    let stderr = eval.child().stderr.take().expect("stderr");
    let (lines_tx, lines_rx) = mpsc::channel();
    let stderr_tx = lines_tx.clone();
    std::thread::spawn(move || {
        for line in std::io::BufRead::lines(std::io::BufReader::new(stdout)).map_while(Result::ok) {
            let _ = lines_tx.send(line);
        }
    });
    std::thread::spawn(move || {
        for line in std::io::BufRead::lines(std::io::BufReader::new(stderr)).map_while(Result::ok) {
            let _ = stderr_tx.send(line);
        }
    });
    // "event=controller_started binary=... pid=N ..." on stderr: kill that process during
    // episode 1.
    let started = loop {
        let line = lines_rx
            .recv_timeout(START)
            .expect("eval starts a controller");
        if line.contains("event=controller_started") {
            break line;
        }
    };
    let pid = started_pid(&started);
    std::thread::sleep(Duration::from_millis(500));
    // SAFETY: kill(2) on the controller eval started; SIGKILL, as a crash would.
    #[allow(unsafe_code)]
    let killed = unsafe { libc::kill(pid, libc::SIGKILL) };
    assert_eq!(killed, 0);
    let status = eval.child().wait().expect("eval ends");
    // The readers end when eval's pipes close; the timeout only guards against a hang.
    let said: Vec<String> =
        std::iter::from_fn(|| lines_rx.recv_timeout(Duration::from_secs(5)).ok()).collect();
    let said = said.join("\n");
    assert!(status.success(), "{said}");
    let episode = |seed: &str| {
        said.lines()
            .find(|l| l.trim_start().starts_with(seed))
            .unwrap_or_else(|| panic!("no episode {seed} in {said}"))
            .to_owned()
    };
    assert!(episode("10000").contains("controller lost"), "{said}");
    assert!(said.contains("the controller died"), "{said}");
    assert!(
        episode("10001").contains("time limit"),
        "a new controller drove: {said}"
    );
    // The first "started" line was read above: this one is the replacement.
    assert_eq!(
        said.matches("event=controller_started").count(),
        1,
        "{said}"
    );
    assert!(
        said.contains("episodes failed because the controller was lost: 1"),
        "{said}"
    );
    // Both controllers' logs are kept.
    let log = std::fs::read_to_string(dir.join("controller.log")).expect("log");
    assert_eq!(log.matches("event=ready").count(), 2, "{log}");
}

/// An eval killed by a signal runs no destructor: the controller it started is sent SIGTERM by
/// the kernel (its parent-death signal) and stops, where it used to wait for the next tick
/// for ever.
#[test]
fn a_killed_eval_takes_the_controller_it_started_with_it() {
    let _serial = one_at_a_time();
    let dir = scratch("eval-killed");
    let name = domain_name("eval-killed");
    let mut eval = spawn_eval(&dir, &name, "10000..10001", "60");
    let stderr = eval.child().stderr.take().expect("stderr");
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(stderr)).map_while(Result::ok);
    let started = lines
        .find(|line| line.contains("event=controller_started"))
        .expect("eval starts a controller");
    let pid = started_pid(&started);
    // The controller ticks in lock step with the episode, then eval is killed as a session's
    // end or `kill -9` would kill it.
    wait_for_text(&dir.join("controller.log"), "event=ready", START);
    std::thread::sleep(Duration::from_millis(300));
    eval.child().kill().expect("kill eval");
    eval.child().wait().expect("reaped");
    // Gone or a zombie awaiting its new parent: no longer running.
    let running = || {
        std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .ok()
            .and_then(|stat| stat.rsplit_once(") ").map(|(_, rest)| rest.to_owned()))
            .is_some_and(|rest| !rest.starts_with('Z'))
    };
    let deadline = Instant::now() + Duration::from_secs(5);
    while running() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    let still_running = running();
    if still_running {
        // SAFETY: kill(2) on the controller the test's eval started: not left behind.
        #[allow(unsafe_code)]
        unsafe {
            libc::kill(pid, libc::SIGKILL);
        }
    }
    assert!(
        !still_running,
        "controller {pid} still runs after its eval was killed"
    );
}

/// The README's evaluation example exactly as a new user types it: no `--domain`, no
/// `DRIBBLE_DOMAIN`, so the simulator and the controller it starts must meet in iceoryx2's
/// default domain.
#[test]
fn the_readme_eval_example_runs_in_the_default_domain() {
    let _serial = one_at_a_time();
    let dir = scratch("readme-eval");
    let repository = support::package_dir();
    std::os::unix::fs::symlink(repository.join("models"), dir.join("models")).expect("link");
    // cargo builds the tool's binaries side by side; eval finds the controller beside itself.
    let _ = controller_binary();
    let output = Command::new(env!("CARGO_BIN_EXE_dribble"))
        .args([
            "eval",
            "--driver",
            "models/fixtures/cnn/policy.toml",
            "--episodes",
            "10000..10002",
        ])
        .current_dir(&dir)
        .env_remove(Domain::ENV)
        .output()
        .expect("dribble runs");
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    assert!(said.contains("event=controller_started"), "{said}");
    assert!(said.contains("domain=default"), "{said}");
    let log = std::fs::read_to_string(dir.join("controller.log")).expect("controller.log");
    assert!(log.contains("event=ready domain=default"), "{log}");
}
