//! What the benchmarks share: where the fixtures are.

use std::path::PathBuf;

/// The fixture policy `kind`'s manifest (`models/fixtures/<kind>/policy.toml`) in the checkout
/// cargo names when it runs the benchmark (`CARGO_MANIFEST_DIR` in the environment: the
/// checkout under test, even when its build directory was shared with a checkout elsewhere),
/// else the one the benchmark was compiled in.
pub fn fixture_manifest(kind: &str) -> PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR")
        .map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), PathBuf::from)
        .join("models/fixtures")
        .join(kind)
        .join("policy.toml")
}
