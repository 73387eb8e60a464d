//! Peak resident memory per run. Linux keeps the process's high-water mark in
//! `/proc/self/status` (`VmHWM`) and resets it when `5` is written to `/proc/self/clear_refs`
//! (Linux ≥ 4.0), so each run's peak is measured from its own start. Where the reset is not
//! permitted the peak is the process's since start, and `reset_peak` says so.

/// Resets the high-water mark; `false` when the kernel refused (the peak then covers the
/// whole process so far).
pub fn reset_peak() -> bool {
    std::fs::write("/proc/self/clear_refs", b"5").is_ok()
}

/// The resident-set high-water mark in MiB, if the platform reports it.
pub fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    parse_kib(&status, "VmHWM:").map(|kib| kib as f64 / 1024.0)
}

fn parse_kib(status: &str, key: &str) -> Option<u64> {
    let line = status.lines().find(|l| l.starts_with(key))?;
    line[key.len()..].split_whitespace().next()?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_status_line() {
        let status = "Name:\tlfr\nVmPeak:\t  200 kB\nVmHWM:\t   12345 kB\nVmRSS:\t 100 kB\n";
        assert_eq!(parse_kib(status, "VmHWM:"), Some(12345));
        assert_eq!(parse_kib(status, "VmSwap:"), None);
    }

    #[test]
    fn the_peak_grows_with_a_large_allocation() {
        // After a reset the high-water mark is the current resident size.
        let (true, Some(before)) = (reset_peak(), peak_rss_mb()) else {
            eprintln!("skipped: this platform cannot reset or report the peak resident size");
            return;
        };
        // Touch 64 MiB so it becomes resident.
        let block = vec![1u8; 64 << 20];
        let after = peak_rss_mb().unwrap();
        assert!(block.iter().step_by(4096).all(|&b| b == 1));
        assert!(after >= before + 60.0, "peak {before} MiB → {after} MiB after touching 64 MiB");
    }
}
