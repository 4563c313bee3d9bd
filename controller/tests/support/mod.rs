//! Shared by the policy tests: the committed fixtures of `models/fixtures`.

#![allow(dead_code)]

use std::fs;
use std::path::PathBuf;
use std::process::Command;

use dribble_controller::{BottomThumbnail, SpeedCommand, TopThumbnail};

/// This package's directory: the one cargo names when it runs the test (`CARGO_MANIFEST_DIR`
/// in the environment: the checkout under test, even when its build directory was shared with
/// a checkout elsewhere), else the one the test was compiled in.
pub fn package_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(
        || env!("CARGO_MANIFEST_DIR").into(),
        std::path::PathBuf::from,
    )
}

pub fn fixture(kind: &str) -> PathBuf {
    package_dir().join("../models/fixtures").join(kind)
}

/// The reference steps PyTorch computed for a fixture.
pub struct Reference {
    pub thumbnails: Vec<(Box<TopThumbnail>, Box<BottomThumbnail>)>,
    pub commands: Vec<[f32; 3]>,
    pub clusters: Option<Vec<usize>>,
    /// The last command fed at each step, for a network that reads it (`previous.f32`);
    /// a stop at every step where the fixture has none.
    pub previous: Vec<SpeedCommand>,
}

pub fn reference(kind: &str) -> Reference {
    let directory = fixture(kind).join("reference");
    let meta: toml::Table = fs::read_to_string(directory.join("reference.toml"))
        .expect("reference.toml")
        .parse()
        .expect("valid TOML");
    let steps = meta["steps"].as_integer().expect("steps") as usize;
    let pixels = fs::read(directory.join("thumbnails.u8")).expect("thumbnails.u8");
    let per_step = TopThumbnail::PIXELS + BottomThumbnail::PIXELS;
    assert_eq!(pixels.len(), steps * per_step);
    let thumbnails = pixels
        .chunks_exact(per_step)
        .map(|step| {
            let (top, bottom) = step.split_at(TopThumbnail::PIXELS);
            (
                Box::new(TopThumbnail::from_bytes(top).expect("top size")),
                Box::new(BottomThumbnail::from_bytes(bottom).expect("bottom size")),
            )
        })
        .collect();
    let triples = |raw: Vec<u8>| {
        raw.chunks_exact(12)
            .map(|c| {
                let value = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
                [value(0), value(4), value(8)]
            })
            .collect::<Vec<_>>()
    };
    let commands = triples(fs::read(directory.join("commands.f32")).expect("commands.f32"));
    assert_eq!(commands.len(), steps);
    let previous = match fs::read(directory.join("previous.f32")) {
        Ok(raw) => triples(raw)
            .into_iter()
            .map(|[f, l, t]| SpeedCommand::new(f, l, t).expect("a finite last command"))
            .collect(),
        Err(_) => vec![SpeedCommand::STOP; steps],
    };
    assert_eq!(previous.len(), steps);
    let clusters = meta.get("clusters").map(|list| {
        list.as_array()
            .expect("clusters list")
            .iter()
            .map(|k| k.as_integer().expect("cluster index") as usize)
            .collect()
    });
    Reference {
        thumbnails,
        commands,
        clusters,
        previous,
    }
}

/// A scratch copy of a fixture directory, for tests that break it.
pub fn scratch_copy(kind: &str, test: &str) -> PathBuf {
    let target = std::env::temp_dir().join(format!("dribble-{test}-{kind}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&target);
    fs::create_dir_all(&target).expect("scratch dir");
    for entry in fs::read_dir(fixture(kind)).expect("fixture dir") {
        let entry = entry.expect("entry");
        if entry.file_type().expect("file type").is_file() {
            fs::copy(entry.path(), target.join(entry.file_name())).expect("copy");
        }
    }
    target
}

/// The controller binary; under `cross/test` it runs on the same emulated CPU as the tests
/// (`DRIBBLE_TEST_RUNNER`, e.g. `qemu-i386 -cpu n270 ...`).
pub fn controller_command() -> Command {
    let binary = env!("CARGO_BIN_EXE_dribble-controller");
    let runner = std::env::var("DRIBBLE_TEST_RUNNER").unwrap_or_default();
    let mut parts = runner.split_whitespace();
    match parts.next() {
        Some(emulator) => {
            let mut command = Command::new(emulator);
            command.args(parts).arg(binary);
            command
        }
        None => Command::new(binary),
    }
}
