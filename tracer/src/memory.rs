//! Memory estimated before allocation: a size within the limits (`limits`) can still exceed the
//! machine — a 32768² render needs about 340 GB — and an allocation that fails aborts the process
//! (or wakes the OOM killer) instead of giving an error. Commands estimate what they will hold
//! and compare it with what the machine has available before any long work.

use crate::error::RenderError;

/// Bytes `lfr render` holds per pixel at its peak: the tiles' double-precision sums, the
/// frame's layers and the EXR's channel copies (measured: 296 B a pixel from 512² to 2048²,
/// peak RSS slope; rounded up).
pub const RENDER_BYTES_PER_PIXEL: u64 = 320;

/// The environment variable that replaces the measured available memory, in bytes: for
/// containers whose limit neither /proc/meminfo nor the cgroup shows, and for tests.
pub const AVAILABLE_OVERRIDE: &str = "LFR_MEMORY_AVAILABLE";

/// The memory available to this process in bytes: the smaller of /proc/meminfo's MemAvailable
/// and the cgroup v2 limit's headroom (memory.max − memory.current), or
/// `$LFR_MEMORY_AVAILABLE`; `None` where neither can be read.
pub fn available_bytes() -> Option<u64> {
    if let Some(value) = std::env::var_os(AVAILABLE_OVERRIDE) {
        return value.to_str().and_then(|v| v.trim().parse().ok());
    }
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok().and_then(|text| {
        text.lines()
            .find_map(|line| line.strip_prefix("MemAvailable:"))
            .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
            .map(|kib| kib * 1024)
    });
    let read = |path: &str| std::fs::read_to_string(path).ok().and_then(|t| t.trim().parse::<u64>().ok());
    let cgroup = match (read("/sys/fs/cgroup/memory.max"), read("/sys/fs/cgroup/memory.current")) {
        (Some(max), Some(current)) => Some(max.saturating_sub(current)),
        _ => None,
    };
    match (meminfo, cgroup) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// `bytes` in the largest unit that keeps it at or above 1 (binary prefixes; one home with the
/// free-space check's, `sampleio::human_bytes`).
pub fn human(bytes: u64) -> String {
    sampleio::human_bytes(bytes)
}

/// Refuses `what` (e.g. "a 32768x32768 render") when it needs more than `needed` bytes than the
/// machine has available; passes where the available memory cannot be read.
pub fn check(what: &str, needed: u64) -> Result<(), RenderError> {
    check_against(what, needed, available_bytes())
}

fn check_against(what: &str, needed: u64, available: Option<u64>) -> Result<(), RenderError> {
    match available {
        Some(available) if needed > available => Err(RenderError::Settings(format!(
            "{what} needs about {} of memory; {} is available (set {AVAILABLE_OVERRIDE} to override the measurement)",
            human(needed),
            human(available)
        ))),
        _ => Ok(()),
    }
}

/// The estimate for a render of `width` × `height` pixels.
pub fn render_bytes(width: u32, height: u32) -> u64 {
    width as u64 * height as u64 * RENDER_BYTES_PER_PIXEL
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_only_what_does_not_fit_and_names_the_sizes() {
        assert!(check_against("x", 10, Some(10)).is_ok());
        assert!(check_against("x", 10, None).is_ok());
        let message =
            check_against("a 32768x32768 render", render_bytes(32768, 32768), Some(16 << 30)).unwrap_err().to_string();
        assert!(message.contains("a 32768x32768 render") && message.contains("320.0 GiB"), "{message}");
        assert!(message.contains("16.0 GiB"), "{message}");
    }

    #[test]
    fn sizes_read_well() {
        assert_eq!(human(512), "512 B");
        assert_eq!(human(1536), "1.5 KiB");
        assert_eq!(human(3 << 30), "3.0 GiB");
    }

    #[test]
    fn this_machine_reports_some_memory() {
        if std::env::var_os(AVAILABLE_OVERRIDE).is_none() && std::path::Path::new("/proc/meminfo").exists() {
            let bytes = available_bytes().expect("readable on Linux");
            assert!(bytes > 1 << 20, "{bytes}");
        }
    }
}
