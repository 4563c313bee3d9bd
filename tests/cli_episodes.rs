//! `dribble record`, `inspect` and `eval` as a team would run them.

mod support;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn dribble(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dribble"))
        .args(args)
        .output()
        .expect("run dribble")
}

fn text(output: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dribble-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    dir
}

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

#[test]
fn recording_is_byte_identical_resumes_and_inspects() {
    let (first, second) = (scratch("record-a"), scratch("record-b"));
    for out in [&first, &second] {
        let output = dribble(&[
            "record",
            "--episodes",
            "5..6",
            "--time-limit",
            "2",
            "--out",
            path(out),
        ]);
        assert!(output.status.success(), "{}", text(&output));
    }
    let file = "episode_00005.npz";
    let bytes = fs::read(first.join(file)).expect("episode written");
    assert_eq!(bytes, fs::read(second.join(file)).expect("episode written"));

    let resumed = dribble(&[
        "record",
        "--episodes",
        "5..7",
        "--time-limit",
        "2",
        "--out",
        path(&first),
    ]);
    let log = text(&resumed);
    assert!(resumed.status.success(), "{log}");
    assert!(log.contains("1 episode(s) already recorded"), "{log}");
    assert!(log.contains("2 episodes"), "{log}");
    assert_eq!(bytes, fs::read(first.join(file)).expect("kept"));
    // dataset.json names every file by its hash, and the whole by a content hash.
    let index = dribble_sim::dataset::DatasetIndex::load(&first)
        .expect("readable")
        .expect("dataset.json");
    assert_eq!(
        index.episodes[0].sha256.as_deref(),
        Some(dribble_sim::dataset::sha256_hex(&bytes).as_str())
    );
    assert!(index.content_hash.is_some());
    assert_eq!(index.content_hash, index.compute_content_hash());
    index.verify(&first).expect("the files are the listed ones");

    let (histograms, sheet) = (first.join("h.png"), first.join("t.png"));
    let inspected = dribble(&[
        "inspect",
        path(&first),
        "--histograms",
        path(&histograms),
        "--thumbnails",
        path(&sheet),
        "--head-pitch-sweep",
    ]);
    let log = text(&inspected);
    assert!(inspected.status.success(), "{log}");
    assert!(log.contains("2 episodes, 120 rows"), "{log}");
    let pitch = dribble_sim::camera_geometry::CameraGeometry::nao()
        .head
        .pitch_deg;
    assert!(
        log.contains(&format!(
            "visibility, head pitch {pitch:.1} deg (as recorded)"
        )),
        "{log}"
    );
    assert!(
        log.contains("head pitch sweep") && log.contains("29.5"),
        "{log}"
    );

    // Data from other cameras is never mixed in: resuming a dataset recorded with another
    // head pitch is refused.
    let mut other = index.clone();
    other.simulator["cameras"]["head"]["pitch_deg"] = serde_json::json!(pitch - 5.0);
    other.save(&second).expect("saved");
    let refused = dribble(&["record", "--episodes", "5..7", "--out", path(&second)]);
    let log = text(&refused);
    assert!(!refused.status.success(), "{log}");
    assert!(
        log.contains("another simulator, camera or expert configuration"),
        "{log}"
    );
    // The message names what differs, and only that.
    assert!(
        log.contains(&format!(
            "cameras.head.pitch_deg: recorded {:?}, now {pitch:?}",
            pitch - 5.0
        )),
        "{log}"
    );
    assert!(
        log.contains("time_limit_s: recorded 2.0, now 90.0"),
        "{log}"
    );
    assert!(!log.contains("cameras.top"), "{log}");
    assert!(histograms.is_file() && sheet.is_file());
    // Nor frames of another sample count: one sample a pixel does not resume four's.
    let refused = dribble(&[
        "record",
        "--episodes",
        "5..8",
        "--time-limit",
        "2",
        "--camera-samples",
        "1",
        "--out",
        path(&first),
    ]);
    let log = text(&refused);
    assert!(!refused.status.success(), "{log}");
    assert!(
        log.contains("camera_samples: recorded null, now 1"),
        "{log}"
    );

    // A file whose array is shorter than its header says is a typed error naming the file
    // and the array, not a panic.
    let damaged = first.join("episode_00006.npz");
    truncate_npz_member(&damaged, "command.npy", 5);
    let inspected = dribble(&["inspect", path(&first)]);
    let log = text(&inspected);
    assert!(!inspected.status.success(), "{log}");
    assert!(!log.contains("panicked"), "{log}");
    assert!(
        log.contains("episode_00006.npz")
            && log.contains("command: shape [60, 3] of <f4 needs 720 bytes, the file holds 715"),
        "{log}"
    );
    for dir in [first, second] {
        fs::remove_dir_all(dir).expect("clean up");
    }
}

#[test]
fn a_killed_recording_resumes_to_the_same_dataset() {
    use dribble_sim::dataset::{DatasetIndex, episode_file};
    use std::time::{Duration, Instant};
    let (killed, fresh) = (scratch("record-killed"), scratch("record-fresh"));
    let args = |out: &Path| -> Vec<String> {
        [
            "record",
            "--episodes",
            "5..8",
            "--time-limit",
            "2",
            "--out",
            path(out),
        ]
        .map(String::from)
        .to_vec()
    };
    // SIGKILL (no chance to clean up) once the first episode is listed.
    let mut child = Command::new(env!("CARGO_BIN_EXE_dribble"))
        .args(args(&killed))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("record starts");
    let deadline = Instant::now() + Duration::from_secs(120);
    let listed = |dir: &Path| {
        DatasetIndex::load(dir)
            .ok()
            .flatten()
            .map_or(0, |index| index.episodes.len())
    };
    while listed(&killed) == 0 {
        assert!(Instant::now() < deadline, "no episode recorded");
        assert!(
            child.try_wait().expect("poll").is_none(),
            "record ended early"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().expect("kill");
    child.wait().expect("reaped");
    let index = DatasetIndex::load(&killed)
        .expect("readable")
        .expect("listed");
    // What a kill can leave of the next episode: a half-written temporary, or a whole file
    // renamed into place but not yet listed. Both are planted here for the first seed the
    // index does not list (the kill may have come at any point).
    let next = (5..8)
        .find(|&seed| index.episodes.iter().all(|e| e.seed != seed))
        .expect("the kill came before the end");
    let file = killed.join(episode_file(next));
    fs::write(file.with_extension("partial"), b"half an episode").expect("plant");
    fs::write(&file, b"not a zip").expect("plant");

    let resumed = dribble(&args(&killed).iter().map(String::as_str).collect::<Vec<_>>());
    let log = text(&resumed);
    assert!(resumed.status.success(), "{log}");
    assert!(
        log.contains(&format!(
            "{} episode(s) already recorded",
            index.episodes.len()
        )),
        "{log}"
    );
    let uninterrupted = dribble(&args(&fresh).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(uninterrupted.status.success(), "{}", text(&uninterrupted));
    for seed in 5..8 {
        let name = episode_file(seed);
        assert!(
            fs::read(killed.join(&name)).expect("episode")
                == fs::read(fresh.join(&name)).expect("episode"),
            "{name} differs from an uninterrupted recording"
        );
    }
    let (a, b) = (
        DatasetIndex::load(&killed)
            .expect("readable")
            .expect("listed"),
        DatasetIndex::load(&fresh)
            .expect("readable")
            .expect("listed"),
    );
    assert_eq!(a.episodes, b.episodes);
    assert_eq!(a.content_hash, b.content_hash);
    a.verify(&killed)
        .expect("every listed file is the one hashed");
    let leftovers: Vec<_> = fs::read_dir(&killed)
        .expect("dir")
        .filter_map(Result::ok)
        .filter(|entry| entry.path().extension().is_some_and(|e| e == "partial"))
        .collect();
    assert!(leftovers.is_empty(), "temporaries left: {leftovers:?}");
    for dir in [killed, fresh] {
        fs::remove_dir_all(dir).expect("clean up");
    }
}

#[test]
fn a_killed_evaluation_resumes_to_the_same_trajectories() {
    use std::time::{Duration, Instant};
    let dir = scratch("eval-killed");
    fs::create_dir_all(&dir).expect("scratch");
    let args = |name: &str, resume: bool| -> Vec<String> {
        let mut args: Vec<String> = [
            "eval",
            "--episodes",
            "10003..10006",
            "--time-limit",
            "40",
            "--trajectories",
            path(&dir.join(format!("{name}.json"))),
            "--plot",
            path(&dir.join(format!("{name}.png"))),
        ]
        .map(String::from)
        .to_vec();
        if resume {
            args.push("--resume".to_owned());
        }
        args
    };
    let journal = dir.join("killed.json.partial");
    // Whole lines only: a kill can land while a line is written (the resume drops it).
    let lines = || fs::read_to_string(&journal).map_or(0, |text| text.matches('\n').count());
    // SIGKILL once the journal holds its settings and the first episode.
    let mut child = Command::new(env!("CARGO_BIN_EXE_dribble"))
        .args(args("killed", false))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("eval starts");
    let deadline = Instant::now() + Duration::from_secs(120);
    while lines() < 2 {
        assert!(Instant::now() < deadline, "no episode in the journal");
        assert!(
            child.try_wait().expect("poll").is_none(),
            "eval ended early"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    child.kill().expect("kill");
    child.wait().expect("reaped");
    let kept = lines() - 1;
    assert!(!dir.join("killed.json").exists(), "cut before the end");
    // A kill while a line was written leaves it torn.
    let mut torn = fs::read(&journal).expect("journal");
    torn.extend_from_slice(b"{\"engine\": null, \"epis");
    fs::write(&journal, torn).expect("tear");

    let play = |args: Vec<String>| dribble(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let resumed = play(args("killed", true));
    let log = text(&resumed);
    assert!(resumed.status.success(), "{log}");
    assert!(
        log.contains(&format!("resume: {kept} episode(s) kept")),
        "{log}"
    );
    assert!(log.contains("a torn line"), "{log}");
    assert!(!journal.exists(), "the journal stays after the run: {log}");
    let whole = play(args("whole", false));
    assert!(whole.status.success(), "{}", text(&whole));
    assert!(
        fs::read(dir.join("killed.json")).expect("resumed file")
            == fs::read(dir.join("whole.json")).expect("whole file"),
        "a resumed run's trajectories differ from an uninterrupted run's"
    );
    let rows = |log: &str| -> Vec<String> {
        log.lines()
            .filter(|line| line.trim_start().starts_with("1000"))
            .map(str::to_owned)
            .collect()
    };
    assert_eq!(rows(&log), rows(&text(&whole)));
    assert_eq!(rows(&log).len(), 3, "{log}");
    fs::remove_dir_all(dir).expect("clean up");
}

#[test]
fn eval_with_the_expert_counts_goals_and_plots() {
    let plot = scratch("eval-plot").with_extension("png");
    let output = dribble(&["eval", "--episodes", "10003..10004", "--plot", path(&plot)]);
    let log = text(&output);
    assert!(output.status.success(), "{log}");
    assert!(log.contains("goals: 1 of 1"), "{log}");
    assert!(log.contains("median time to goal"), "{log}");
    assert!(log.contains("controller tick latency"), "{log}");
    assert!(plot.is_file());
    fs::remove_file(plot).expect("clean up");
}

#[test]
fn eval_drives_with_a_learned_policy_through_the_rendered_cameras() {
    let plot = scratch("eval-policy").with_extension("png");
    let trajectories = scratch("eval-policy").with_extension("json");
    let manifest = support::fixture_manifest("cnn");
    let output = dribble(&[
        "eval",
        "--driver",
        path(&manifest),
        "--episodes",
        "10000..10001",
        "--time-limit",
        "2",
        "--plot",
        path(&plot),
        // The controller process (the default) is tested in controller_process.rs.
        "--transport",
        "in-process",
        // One sample a pixel (four everywhere else in the suite), named in the file.
        "--camera-samples",
        "1",
        "--trajectories",
        path(&trajectories),
    ]);
    let log = text(&output);
    assert!(output.status.success(), "{log}");
    assert!(log.contains("camera samples: 1"), "{log}");
    let written: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(&trajectories).expect("written")).expect("json");
    assert_eq!(written["camera_samples"], 1, "{written}");
    assert!(log.contains("driver: CNN policy"), "{log}");
    assert!(log.contains("in-process (controller thread)"), "{log}");
    assert!(log.contains("adapter: "), "{log}");
    // Random weights: no goal, but a command for every camera pair (60 in 2 s, the first
    // pair completing half a period in).
    assert!(log.contains("goals: 0 of 1"), "{log}");
    let row = log
        .lines()
        .find(|line| line.trim_start().starts_with("10000 "))
        .unwrap_or_else(|| panic!("no row for episode 10000: {log}"));
    let fields: Vec<&str> = row.split_whitespace().collect();
    assert_eq!(
        (fields[1..3].join(" ").as_str(), fields.last().copied()),
        ("time limit", Some("60")),
        "{row}"
    );
    fs::remove_file(plot).expect("clean up");
    fs::remove_file(trajectories).expect("clean up");
}

/// Rewrites the `.npz` at `path` with `member`'s bytes shortened by `by` (a valid zip whose
/// array lies about its length).
fn truncate_npz_member(path: &Path, member: &str, by: usize) {
    use std::io::{Cursor, Read, Write};
    let mut archive =
        zip::ZipArchive::new(Cursor::new(fs::read(path).expect("read"))).expect("zip");
    let mut writer = zip::ZipWriter::new(Cursor::new(Vec::new()));
    for i in 0..archive.len() {
        let mut file = archive.by_index(i).expect("member");
        let name = file.name().expect("name").to_string();
        let mut bytes = Vec::new();
        file.read_to_end(&mut bytes).expect("member bytes");
        if name == member {
            bytes.truncate(bytes.len() - by);
        }
        writer
            .start_file(name, zip::write::SimpleFileOptions::default())
            .expect("start");
        writer.write_all(&bytes).expect("write");
    }
    let bytes = writer.finish().expect("finish").into_inner();
    fs::write(path, bytes).expect("write back");
}

#[test]
fn episodes_in_parallel_jobs_end_as_in_one_serial_run() {
    let policy = support::package_dir().join("models/policy/cnn-modal-dagger4/policy.toml");
    let run = |name: &str, jobs: &str| {
        let out = scratch(name);
        fs::create_dir_all(&out).expect("scratch");
        let trajectories = out.join("trajectories.json");
        let output = dribble(&[
            "eval",
            "--driver",
            path(&policy),
            "--episodes",
            "20000..20004",
            "--time-limit",
            "4",
            "--isa",
            "portable",
            "--jobs",
            jobs,
            "--domain",
            &format!("dribble-jobs-test-{name}-{}", std::process::id()),
            "--plot",
            path(&out.join("plot.png")),
            "--trajectories",
            path(&trajectories),
            "--controller-log",
            path(&out.join("controller.log")),
            // Nothing to resume from: every episode is played (and the journals go).
            "--resume",
        ]);
        let log = text(&output);
        assert!(output.status.success(), "{log}");
        assert!(out.join("plot.png").is_file(), "{log}");
        let leftovers: Vec<_> = fs::read_dir(&out)
            .expect("dir")
            .filter_map(Result::ok)
            .map(|entry| entry.file_name())
            .filter(|name| name.to_string_lossy().contains(".json."))
            .collect();
        assert!(
            leftovers.is_empty(),
            "journals or job files left: {leftovers:?}"
        );
        let file: serde_json::Value =
            serde_json::from_str(&fs::read_to_string(&trajectories).expect("trajectories"))
                .expect("json");
        fs::remove_dir_all(out).expect("clean up");
        (log, file)
    };
    let (serial_log, serial) = run("serial", "1");
    let (jobs_log, jobs) = run("jobs", "2");
    assert!(
        jobs_log.contains("job 1: seeds 20002..20004 done"),
        "{jobs_log}"
    );
    // Every episode's outcome, duration, commands and 10 Hz paths, to the bit; the engine too.
    assert_eq!(serial, jobs, "serial:\n{serial_log}\njobs:\n{jobs_log}");
    let rows = |log: &str| -> Vec<String> {
        log.lines()
            .filter(|line| line.trim_start().starts_with("2000"))
            .map(str::to_owned)
            .collect()
    };
    assert_eq!(rows(&serial_log), rows(&jobs_log));
    assert_eq!(rows(&serial_log).len(), 4, "{serial_log}");
}
