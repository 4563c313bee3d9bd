//! `dribble record`, `inspect` and `eval` as a team would run them.

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
    for dir in [first, second] {
        fs::remove_dir_all(dir).expect("clean up");
    }
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
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/fixtures/cnn/policy.toml");
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
    ]);
    let log = text(&output);
    assert!(output.status.success(), "{log}");
    assert!(log.contains("driver: CNN policy"), "{log}");
    assert!(log.contains("in-process (controller thread)"), "{log}");
    assert!(log.contains("adapter: "), "{log}");
    // Random weights: no goal, but a command for every camera pair (60 in 2 s, the first
    // pair completing half a period in).
    assert!(log.contains("goals: 0 of 1"), "{log}");
    assert!(log.contains("time limit"), "{log}");
    fs::remove_file(plot).expect("clean up");
}
