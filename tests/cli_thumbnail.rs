//! `dribble thumbnail` on raw frame files, as a team would use it on a camera dump.

use std::fs;
use std::path::PathBuf;
use std::process::Command;

fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dribble-test-{name}-{}", std::process::id()));
    fs::create_dir_all(&dir).expect("create scratch dir");
    dir
}

fn dribble(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dribble"))
        .args(args)
        .output()
        .expect("run dribble")
}

#[test]
fn writes_the_thumbnail_the_policy_sees_as_pgm() {
    let dir = scratch_dir("thumbnail");
    let input = dir.join("bottom.yuyv");
    // Luma 100 everywhere, chroma 200: the thumbnail must be 100 everywhere.
    let frame: Vec<u8> = (0..320 * 240 * 2)
        .map(|i| if i % 2 == 0 { 100 } else { 200 })
        .collect();
    fs::write(&input, frame).expect("write frame");
    let output_path = dir.join("bottom.pgm");
    let output = dribble(&[
        "thumbnail",
        "--camera",
        "bottom",
        input.to_str().expect("utf-8 path"),
        "--out",
        output_path.to_str().expect("utf-8 path"),
    ]);
    assert!(output.status.success(), "{output:?}");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("0.000 1.000 0.000 0.000 0.000"), "{stdout}");
    let pgm = fs::read(&output_path).expect("read pgm");
    let header = b"P5\n80 60\n255\n";
    assert_eq!(&pgm[..header.len()], header);
    assert_eq!(pgm.len(), header.len() + 80 * 60);
    assert!(pgm[header.len()..].iter().all(|&p| p == 100));
    fs::remove_dir_all(dir).expect("clean up");
}

#[test]
fn a_frame_of_the_wrong_size_is_refused_with_the_sizes_named() {
    let dir = scratch_dir("wrong-size");
    let input = dir.join("bottom.yuyv");
    fs::write(&input, vec![0u8; 320 * 240 * 2]).expect("write frame");
    let output = dribble(&[
        "thumbnail",
        "--camera",
        "top",
        input.to_str().expect("utf-8 path"),
        "--out",
        dir.join("x.pgm").to_str().expect("utf-8 path"),
    ]);
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains("a 640x480 YUYV frame has 614400 bytes, found 153600"),
        "{stderr}"
    );
    assert!(!dir.join("x.pgm").exists());
    fs::remove_dir_all(dir).expect("clean up");
}
