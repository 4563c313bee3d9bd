//! Shared by the whole-system tests.

#![allow(dead_code)]

pub mod counting_allocator;

use std::path::{Path, PathBuf};

/// The manifest of a committed fixture policy (`models/fixtures/<kind>/policy.toml`).
pub fn fixture_manifest(kind: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("models/fixtures")
        .join(kind)
        .join("policy.toml")
}
