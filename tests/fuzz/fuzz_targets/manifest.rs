//! `policy.toml` manifests: any text. The contract: a typed error naming the file, never a
//! panic; an accepted manifest names only network files inside its directory.
#![no_main]

use std::path::{Component, Path};

use dribble_controller::policy::manifest::PolicyManifest;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("/robot/models/policy/policy.toml");
    match PolicyManifest::parse(text, path) {
        Ok(manifest) => {
            for network in manifest.network_paths() {
                let inside = network
                    .strip_prefix("/robot/models/policy")
                    .expect("under the directory");
                assert!(
                    inside
                        .components()
                        .all(|c| matches!(c, Component::Normal(_))),
                    "{network:?}"
                );
            }
        }
        Err(error) => assert!(error.to_string().contains("policy.toml"), "{error}"),
    }
});
