//! Notices that a loaded policy's files were replaced on disk. The controller keeps running
//! the networks it loaded (a half-copied model must never reach the walk mid-game); it only
//! says so, once, so that whoever copied the new model knows a restart is needed.
//!
//! Polled from the control thread about once a second: `stat(2)` on a path prepared at
//! start-up, so a poll allocates nothing.

use std::ffi::CString;
use std::path::{Path, PathBuf};

/// What identifies a file's contents without reading them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Identity {
    device: u64,
    inode: u64,
    size: i64,
    modified_s: i64,
    modified_ns: i64,
}

/// Watches one file (the manifest, or a network file) for replacement or change.
#[derive(Debug)]
pub struct PolicyFileWatch {
    path: PathBuf,
    c_path: CString,
    loaded: Option<Identity>,
    reported: bool,
}

impl PolicyFileWatch {
    /// Starts watching `path` as it is now (the file just loaded).
    pub fn new(path: &Path) -> Option<Self> {
        use std::os::unix::ffi::OsStrExt;
        let c_path = CString::new(path.as_os_str().as_bytes()).ok()?;
        let mut watch = Self {
            path: path.to_owned(),
            c_path,
            loaded: None,
            reported: false,
        };
        watch.loaded = watch.identity();
        Some(watch)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    #[allow(unsafe_code)]
    fn identity(&self) -> Option<Identity> {
        // SAFETY: an all-zero `stat` is a valid value to be overwritten; `c_path` is a
        // NUL-terminated path that outlives the call.
        let mut status: libc::stat = unsafe { std::mem::zeroed() };
        let result = unsafe { libc::stat(self.c_path.as_ptr(), &mut status) };
        (result == 0).then_some(Identity {
            device: status.st_dev as u64,
            inode: status.st_ino as u64,
            size: status.st_size as i64,
            modified_s: status.st_mtime as i64,
            modified_ns: status.st_mtime_nsec as i64,
        })
    }

    /// True once, the first time the file is found replaced, changed or gone.
    pub fn changed(&mut self) -> bool {
        if self.reported {
            return false;
        }
        if self.identity() != self.loaded {
            self.reported = true;
            return true;
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_replaced_file_is_reported_once() {
        let directory = std::env::temp_dir().join(format!("dribble-watch-{}", std::process::id()));
        std::fs::create_dir_all(&directory).expect("dir");
        let path = directory.join("policy.onnx");
        std::fs::write(&path, b"first").expect("write");
        let mut watch = PolicyFileWatch::new(&path).expect("a path");
        assert!(!watch.changed(), "unchanged");
        // Replaced the way a copy tool does it: a new file renamed over the old one.
        let new = directory.join("policy.onnx.new");
        std::fs::write(&new, b"second, longer").expect("write");
        std::fs::rename(&new, &path).expect("rename");
        assert!(watch.changed());
        assert!(!watch.changed(), "once");
        std::fs::remove_dir_all(directory).expect("clean up");
    }
}
