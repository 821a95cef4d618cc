//! What the machine can hold: memory a request needs, checked against what is available
//! before the work starts, so that a request too large is refused with a message instead of
//! aborting on a failed allocation.

use crate::MediumError;

/// Memory available to new allocations, in bytes: the system's `MemAvailable` (Linux), or
/// what this process's cgroup still allows when that is less (a container's limit, which
/// `MemAvailable` does not show); `None` where neither can be read.
pub fn available_memory() -> Option<u64> {
    let system = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| mem_available(&text));
    let cgroup = cgroup_headroom();
    match (system, cgroup) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// `MemAvailable` from the text of `/proc/meminfo`, in bytes.
fn mem_available(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line
        .trim_start_matches("MemAvailable:")
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    kib.checked_mul(1024)
}

/// The cgroup's limit minus its usage: cgroup v2 (`memory.max`, `memory.current`) or v1
/// (`memory.limit_in_bytes`, `memory.usage_in_bytes`) at the root of the process's view.
fn cgroup_headroom() -> Option<u64> {
    let read = |path: &str| std::fs::read_to_string(path).ok();
    let v2 = || {
        headroom(
            &read("/sys/fs/cgroup/memory.max")?,
            &read("/sys/fs/cgroup/memory.current")?,
        )
    };
    let v1 = || {
        headroom(
            &read("/sys/fs/cgroup/memory/memory.limit_in_bytes")?,
            &read("/sys/fs/cgroup/memory/memory.usage_in_bytes")?,
        )
    };
    v2().or_else(v1)
}

/// `limit − usage` from a cgroup's files; `None` without a limit (`max`, or v1's huge
/// "unlimited" value).
fn headroom(limit: &str, usage: &str) -> Option<u64> {
    let limit: u64 = limit.trim().parse().ok()?;
    if limit >= 1 << 60 {
        return None;
    }
    let usage: u64 = usage.trim().parse().ok()?;
    Some(limit.saturating_sub(usage))
}

/// Refuses `bytes` for `what` when they exceed the available memory (a machine that does not
/// say is not refused).
pub fn check_memory(what: &str, bytes: u64) -> Result<(), MediumError> {
    match available_memory() {
        Some(available) if bytes > available => Err(MediumError::invalid(
            "memory",
            format!(
                "{what} needs about {} but this machine has {} available",
                gib(bytes),
                gib(available)
            ),
        )),
        _ => Ok(()),
    }
}

fn gib(bytes: u64) -> String {
    format!("{:.1} GiB", bytes as f64 / (1u64 << 30) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn available_memory_reads_meminfo_and_cgroup_limits() {
        let meminfo =
            "MemTotal:       24683584 kB\nMemFree:  100 kB\nMemAvailable:   23290824 kB\n";
        assert_eq!(mem_available(meminfo), Some(23290824 * 1024));
        assert_eq!(mem_available("MemTotal: 5 kB\n"), None);
        assert_eq!(headroom("4294967296\n", "1073741824\n"), Some(3 << 30));
        assert_eq!(headroom("max\n", "1073741824\n"), None);
        // cgroup v1 writes a page-rounded i64::MAX for "no limit".
        assert_eq!(headroom("9223372036854771712\n", "5\n"), None);
        assert_eq!(headroom("100", "200"), Some(0));
    }

    #[test]
    fn more_than_the_machine_has_is_refused_and_a_little_is_not() {
        assert!(check_memory("a byte", 1).is_ok());
        if let Some(available) = available_memory() {
            assert!(available > 0);
            let err = check_memory("the test", u64::MAX).unwrap_err().to_string();
            assert!(
                err.contains("the test") && err.contains("available"),
                "{err}"
            );
        }
    }
}
