//! Real-time settings for the control thread, as the field's real-time stacks set them (ROS 2's
//! real-time guidance, B-Human's and HULKs' frameworks): memory locked so a page fault never
//! lands in a tick, a `SCHED_FIFO` priority above ordinary processes, and the thread pinned
//! to one CPU.
//!
//! Each setting is asked for separately and may be refused (no privilege, no such CPU): the
//! [`RealtimeReport`] says which took effect and why the others did not, so the caller can
//! log a warning and run on, or refuse to start (`--require-realtime`).
//!
//! Linux only, through `libc` (the calls are a few lines each; no crate adds anything here).

use std::fmt;

/// What to ask of the kernel for the calling thread (and, for memory, the whole process).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RealtimeRequest {
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)`, and the stack touched ahead of use.
    pub lock_memory: bool,
    /// `SCHED_FIFO` at this priority (1 to 99), for the calling thread.
    pub fifo_priority: Option<u8>,
    /// Run the calling thread on this CPU only.
    pub cpu: Option<usize>,
}

/// One real-time setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Setting {
    LockMemory,
    Fifo(u8),
    Cpu(usize),
}

impl fmt::Display for Setting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::LockMemory => write!(f, "memory locked (mlockall)"),
            Self::Fifo(priority) => write!(f, "SCHED_FIFO priority {priority}"),
            Self::Cpu(cpu) => write!(f, "pinned to CPU {cpu}"),
        }
    }
}

/// A setting the kernel (or this machine) refused, and why.
#[derive(Debug)]
pub struct Refusal {
    pub setting: Setting,
    pub reason: String,
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} refused: {}", self.setting, self.reason)
    }
}

/// What [`apply`] achieved.
#[derive(Debug, Default)]
pub struct RealtimeReport {
    pub in_force: Vec<Setting>,
    pub refused: Vec<Refusal>,
}

impl RealtimeReport {
    /// "memory locked (mlockall), SCHED_FIFO priority 40", or "none".
    pub fn in_force_text(&self) -> String {
        if self.in_force.is_empty() {
            return "none".into();
        }
        self.in_force
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Bytes of stack touched after locking memory, so the deepest tick finds its pages mapped.
const STACK_PREFAULT_BYTES: usize = 256 * 1024;

/// Applies `request` to the calling thread; never fails, reports instead.
pub fn apply(request: RealtimeRequest) -> RealtimeReport {
    let mut report = RealtimeReport::default();
    let mut record = |setting: Setting, result: Result<(), String>| match result {
        Ok(()) => report.in_force.push(setting),
        Err(reason) => report.refused.push(Refusal { setting, reason }),
    };
    if let Some(cpu) = request.cpu {
        record(Setting::Cpu(cpu), pin_to_cpu(cpu));
    }
    if let Some(priority) = request.fifo_priority {
        record(Setting::Fifo(priority), fifo(priority));
    }
    if request.lock_memory {
        record(Setting::LockMemory, lock_memory());
    }
    report
}

fn os_error(call: &str) -> String {
    let error = std::io::Error::last_os_error();
    let hint = match error.raw_os_error() {
        Some(libc::EPERM) => " (needs root, CAP_SYS_NICE or an RLIMIT_RTPRIO allowance)",
        Some(libc::ENOMEM) | Some(libc::EAGAIN) => {
            " (needs root, CAP_IPC_LOCK or a larger RLIMIT_MEMLOCK: ulimit -l)"
        }
        _ => "",
    };
    format!("{call}: {error}{hint}")
}

#[allow(unsafe_code)]
fn pin_to_cpu(cpu: usize) -> Result<(), String> {
    let online = std::thread::available_parallelism().map_or(1, usize::from);
    // SAFETY: sysconf only reads a configuration value.
    let configured = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_CONF) };
    let configured = usize::try_from(configured).unwrap_or(online);
    if cpu >= configured.max(online) || cpu >= libc::CPU_SETSIZE as usize {
        return Err(format!(
            "no CPU {cpu} on this machine ({} configured)",
            configured.max(online)
        ));
    }
    // SAFETY: a zeroed cpu_set_t is the empty set; CPU_SET writes inside it (cpu is below
    // CPU_SETSIZE); sched_setaffinity reads size_of::<cpu_set_t>() bytes of it.
    let result = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, size_of::<libc::cpu_set_t>(), &set)
    };
    if result == 0 {
        Ok(())
    } else {
        Err(os_error("sched_setaffinity"))
    }
}

#[allow(unsafe_code)]
fn fifo(priority: u8) -> Result<(), String> {
    // SAFETY: these only read the scheduler's limits.
    let (min, max) = unsafe {
        (
            libc::sched_get_priority_min(libc::SCHED_FIFO),
            libc::sched_get_priority_max(libc::SCHED_FIFO),
        )
    };
    if !(min..=max).contains(&i32::from(priority)) {
        return Err(format!(
            "priority {priority} is outside SCHED_FIFO's {min}..={max}"
        ));
    }
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: pid 0 is the calling thread; param is a valid sched_param for the call.
    let result = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if result == 0 {
        Ok(())
    } else {
        Err(os_error("sched_setscheduler"))
    }
}

#[allow(unsafe_code)]
fn lock_memory() -> Result<(), String> {
    // SAFETY: mlockall takes flags only.
    let result = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if result != 0 {
        return Err(os_error("mlockall"));
    }
    prefault_stack();
    Ok(())
}

/// Touches `STACK_PREFAULT_BYTES` of stack, so that with memory locked those pages are
/// resident before the first tick needs them.
#[inline(never)]
fn prefault_stack() {
    let mut block = [0u8; STACK_PREFAULT_BYTES];
    for byte in block.iter_mut().step_by(4096) {
        // Volatile-like: black_box keeps the writes.
        *std::hint::black_box(byte) = 1;
    }
    std::hint::black_box(&block);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cpu_that_does_not_exist_is_refused_by_name() {
        let report = apply(RealtimeRequest {
            cpu: Some(100_000),
            ..RealtimeRequest::default()
        });
        assert!(report.in_force.is_empty());
        let [refusal] = report.refused.as_slice() else {
            panic!("{report:?}");
        };
        assert_eq!(refusal.setting, Setting::Cpu(100_000));
        assert!(refusal.reason.contains("no CPU 100000"), "{refusal}");
    }

    #[test]
    fn an_out_of_range_priority_is_refused() {
        let report = apply(RealtimeRequest {
            fifo_priority: Some(0),
            ..RealtimeRequest::default()
        });
        assert!(
            report.refused[0].reason.contains("outside SCHED_FIFO"),
            "{report:?}"
        );
    }

    #[test]
    fn nothing_asked_nothing_in_force() {
        let report = apply(RealtimeRequest::default());
        assert!(report.in_force.is_empty() && report.refused.is_empty());
        assert_eq!(report.in_force_text(), "none");
    }
}
