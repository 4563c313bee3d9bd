//! Shared by the whole-system tests.

#![allow(dead_code)]

pub mod counting_allocator;

use std::path::{Path, PathBuf};

/// Installs the binaries' log subscriber (logfmt on stderr) with every level enabled, once
/// per test process, so that an allocation test counts whatever a log event on the tick's
/// path would cost.
/// This package's directory: the one cargo names when it runs the test (`CARGO_MANIFEST_DIR`
/// in the environment: the checkout under test, even when its build directory was shared with
/// a checkout elsewhere), else the one the test was compiled in.
pub fn package_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(
        || env!("CARGO_MANIFEST_DIR").into(),
        std::path::PathBuf::from,
    )
}

pub fn install_log_subscriber() {
    static INSTALLED: std::sync::Once = std::sync::Once::new();
    INSTALLED.call_once(|| {
        use dribble_controller::log_output::{LogFormat, install_with_filter};
        install_with_filter(LogFormat::Logfmt, "trace").expect("the first subscriber installs");
    });
    assert!(tracing::dispatcher::has_been_set());
}

/// The manifest of a committed fixture policy (`models/fixtures/<kind>/policy.toml`).
pub fn fixture_manifest(kind: &str) -> PathBuf {
    package_dir()
        .join("models/fixtures")
        .join(kind)
        .join("policy.toml")
}

/// The `dribble-controller` binary of this build, built first if needed (cargo builds only
/// the tested package's binaries for its tests).
///
/// It is built as `cargo test --workspace --all-targets` (the suite, `scripts/test`) builds
/// it: the whole workspace and one of the controller's test targets, so that cargo resolves
/// the dependencies' features with the dev-dependencies in, as the suite does. Under the
/// suite the binary is then already fresh; `-p dribble-controller` alone would resolve other
/// features and build the controller and a third of its dependencies again (6.5 minutes of a
/// cold suite), and overwrite the binary the other stages run.
pub fn controller_binary() -> PathBuf {
    static BUILT: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    BUILT
        .get_or_init(|| {
            let dribble = Path::new(env!("CARGO_BIN_EXE_dribble"));
            let profile_dir = dribble.parent().expect("a target directory");
            let target_dir = profile_dir.parent().expect("a target directory");
            let mut build = std::process::Command::new(env!("CARGO"));
            build
                .args(["build", "--quiet", "--workspace"])
                .args(["--bin", "dribble-controller", "--test", "transport"])
                .env("CARGO_TARGET_DIR", target_dir)
                .current_dir(package_dir());
            if profile_dir.ends_with("release") {
                build.arg("--release");
            }
            let status = build.status().expect("cargo runs");
            assert!(status.success(), "building dribble-controller failed");
            profile_dir.join("dribble-controller")
        })
        .clone()
}

/// A fresh directory for one test's files.
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dribble-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

/// The iceoryx2 domain of one test: no other test uses it, and a crashed run's leftovers
/// are cleaned up by the next run.
pub fn domain_name(test: &str) -> String {
    format!("test-{test}")
}

/// Waits until `path` contains `needle`; returns the whole text.
pub fn wait_for_text(path: &Path, needle: &str, timeout: std::time::Duration) -> String {
    let deadline = std::time::Instant::now() + timeout;
    loop {
        let text = std::fs::read_to_string(path).unwrap_or_default();
        if text.contains(needle) {
            return text;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "{} never said {needle:?}; it said:\n{text}",
            path.display()
        );
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}
