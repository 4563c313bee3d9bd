//! Episode files (`.npz`) as `dribble inspect`, `score` and the trainer's checks read them:
//! any bytes. The contract: a typed error naming the file, or arrays whose data length is
//! what their header's shape and type say.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use dribble_sim::dataset::read_npz;
use libfuzzer_sys::fuzz_target;

fn scratch() -> &'static PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        PathBuf::from(format!(
            "/dev/shm/dribble-fuzz-npz-{}.npz",
            std::process::id()
        ))
    })
}

fuzz_target!(|data: &[u8]| {
    std::fs::write(scratch(), data).expect("scratch file");
    match read_npz(scratch()) {
        Ok(arrays) => {
            for (name, array) in arrays {
                let size = match array.descr.as_str() {
                    "|u1" | "|i1" | "|b1" => 1,
                    "<f4" | "<i4" | "<u4" => 4,
                    _ => 8,
                };
                let elements: usize = array.shape.iter().product();
                assert_eq!(array.data.len(), elements * size, "{name}");
            }
        }
        Err(error) => assert!(error.to_string().contains("dribble-fuzz-npz"), "{error}"),
    }
});
