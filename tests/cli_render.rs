//! `dribble render` writes the pictures it promises.

use std::fs;
use std::process::Command;

#[test]
fn render_writes_camera_images_thumbnails_and_a_top_view() {
    let out = std::env::temp_dir().join(format!("dribble-render-{}", std::process::id()));
    let output = Command::new(env!("CARGO_BIN_EXE_dribble"))
        .args([
            "render",
            "--seed",
            "3",
            "--seconds",
            "0.5",
            "--forward",
            "1",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("run dribble render");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{}\n{stdout}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(stdout.starts_with("adapter: "), "{stdout}");
    for (name, width, height) in [
        ("top.png", 640, 480),
        ("bottom.png", 320, 240),
        ("top_thumbnail.png", 640, 480),
        ("bottom_thumbnail.png", 640, 480),
        ("top_view.png", 832, 592),
    ] {
        let bytes = fs::read(out.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(&bytes[1..4], b"PNG", "{name}");
        let size = |at: usize| {
            u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
        };
        assert_eq!((size(16), size(20)), (width, height), "{name}");
    }
    fs::remove_dir_all(out).expect("clean up");
}
