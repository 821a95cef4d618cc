//! What the machine can hold: memory a request needs, checked against what is available
//! before the work starts, so that a request too large is refused with a message instead of
//! aborting on a failed allocation.

use crate::MediumError;

/// Memory the system reports as available to new allocations (Linux `MemAvailable`), in
/// bytes; `None` where it cannot be read.
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line
        .trim_start_matches("MemAvailable:")
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    kib.checked_mul(1024)
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
