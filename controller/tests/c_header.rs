//! `include/dribble_messages.h` describes the messages as the Rust types lay them out: a C
//! compiler checks the header's own sizes and offsets (static assertions, for 32 and 64
//! bit when the compiler can), and this test checks the Rust side against the same numbers.

mod support;

use std::mem::{offset_of, size_of};
use std::process::Command;

use dribble_controller::frame::{BottomFrame, FrameHeader, TopFrame, YUYV_FOURCC};
use dribble_controller::motion_command::{CommandFlags, MotionCommand};
use dribble_controller::transport::LockStepTick;
use dribble_controller::transport::ipc::{
    BOTTOM_CAMERA_SERVICE, COMMAND_SERVICE, TICK_SERVICE, TOP_CAMERA_SERVICE,
};

fn header() -> String {
    let path = support::package_dir().join("include/dribble_messages.h");
    std::fs::read_to_string(path).expect("the header")
}

#[test]
fn the_header_states_the_rust_layouts() {
    assert_eq!(size_of::<FrameHeader>(), 32);
    assert_eq!(offset_of!(FrameHeader, width), 16);
    assert_eq!(offset_of!(FrameHeader, format), 24);
    assert_eq!(size_of::<TopFrame>(), 614_432);
    assert_eq!(size_of::<BottomFrame>(), 153_632);
    assert_eq!(size_of::<MotionCommand>(), 48);
    assert_eq!(offset_of!(MotionCommand, speed), 32);
    assert_eq!(offset_of!(MotionCommand, flags), 44);
    assert_eq!(size_of::<LockStepTick>(), 24);
    let text = header();
    for needle in [
        format!("sizeof(dribble_top_frame) == {}", size_of::<TopFrame>()),
        format!(
            "sizeof(dribble_bottom_frame) == {}",
            size_of::<BottomFrame>()
        ),
        format!(
            "sizeof(dribble_motion_command) == {}",
            size_of::<MotionCommand>()
        ),
        format!("DRIBBLE_YUYV_FOURCC {YUYV_FOURCC:#010x}u"),
        format!("DRIBBLE_COMMAND_NEW {}u", CommandFlags::NEW.0),
        format!("DRIBBLE_COMMAND_REPEATED {}u", CommandFlags::REPEATED.0),
        format!("DRIBBLE_COMMAND_STOP {}u", CommandFlags::STOP.0),
        format!("\"{TOP_CAMERA_SERVICE}\""),
        format!("\"{BOTTOM_CAMERA_SERVICE}\""),
        format!("\"{COMMAND_SERVICE}\""),
        format!("\"{TICK_SERVICE}\""),
    ] {
        assert!(text.contains(&needle), "the header lacks {needle}");
    }
}

/// Compiles the header with `compiler`; false if there is no such compiler here.
fn compiles_with(compiler: &str) -> bool {
    let path = support::package_dir().join("include/dribble_messages.h");
    let Ok(output) = Command::new(compiler)
        .args(["-std=c11", "-Wall", "-Werror", "-fsyntax-only", "-x", "c"])
        .arg(&path)
        .output()
    else {
        eprintln!("no {compiler} here");
        return false;
    };
    assert!(
        output.status.success(),
        "{compiler}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    true
}

#[test]
fn c_compilers_accept_the_header() {
    // The host's (64-bit) and the Nao V5's (32-bit) compilers, where installed. One of them
    // must be: the host's `cc` links every Rust build, and `cross/test` (which sets
    // DRIBBLE_TEST_RUNNER and runs this test on the emulated Atom) installs the 32-bit one,
    // so there the 32-bit layouts of the header are checked by the compiler too.
    let required = if std::env::var_os("DRIBBLE_TEST_RUNNER").is_some() {
        "i686-linux-gnu-gcc"
    } else {
        "cc"
    };
    let compiled: Vec<&str> = ["cc", "i686-linux-gnu-gcc"]
        .into_iter()
        .filter(|compiler| compiles_with(compiler))
        .collect();
    assert!(
        compiled.contains(&required),
        "{required} did not check the header (checked by: {compiled:?})"
    );
}
