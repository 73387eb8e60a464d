//! [`skip`]: a test case that cannot run on this machine (a missing peer such as Python,
//! `pyoidn`, `flip_evaluator` or Chromium; a case that needs root) is never a silent pass. Under
//! CI (`LFR_CI=1`, set by `.ci/run`) it fails; elsewhere it writes `SKIPPED <case>: <why>` to
//! the process's standard error directly, where the test harness does not capture it, so the
//! output of `cargo test` names every case that did not run.
//!
//! [`skip_unless_unprivileged`]: a case that only an unprivileged user can run (permissions
//! that root ignores). CI runs the tests as root and then these cases again as an unprivileged
//! user with `LFR_CI_UNPRIVILEGED=1`, where they must run.

use std::io::Write;

/// The variable `.ci/run` sets: every case must run.
pub const CI_VARIABLE: &str = "LFR_CI";
/// The variable of CI's unprivileged pass: the cases that need an unprivileged user must run.
pub const UNPRIVILEGED_VARIABLE: &str = "LFR_CI_UNPRIVILEGED";

fn set(variable: &str) -> bool {
    std::env::var(variable).is_ok_and(|v| v == "1")
}

/// Whether this run is CI's (`LFR_CI=1`), where no case may be skipped.
pub fn in_ci() -> bool {
    set(CI_VARIABLE)
}

/// The line [`skip`] writes for `case`.
pub fn skip_line(case: &str, why: &str) -> String {
    format!("SKIPPED {case}: {why}")
}

/// The running test's name: libtest names each test's thread after it.
pub fn current_case() -> String {
    std::thread::current().name().unwrap_or("a test").to_string()
}

/// Skips the running test's case because of `why`: a panic under CI, a line on the uncaptured
/// standard error elsewhere. The caller returns from the test after it.
#[track_caller]
pub fn skip(why: &str) {
    let case = current_case();
    if in_ci() {
        panic!("{case} cannot run ({why}), and under CI ({CI_VARIABLE}=1) every case must run");
    }
    let _ = writeln!(std::io::stderr(), "{}", skip_line(&case, why));
}

/// Skips the running test's case, which needs an unprivileged user (it relies on permissions root ignores), when
/// this process is privileged: loudly outside CI and in CI's root pass, which leaves the case to
/// CI's unprivileged pass; a failure in that pass (`LFR_CI_UNPRIVILEGED=1`), where it must run.
#[track_caller]
pub fn skip_unless_unprivileged(why: &str) {
    let case = current_case();
    if set(UNPRIVILEGED_VARIABLE) {
        panic!("{case} cannot run ({why}) in CI's unprivileged pass ({UNPRIVILEGED_VARIABLE}=1)");
    }
    let pass = if in_ci() { "; CI runs it in its unprivileged pass" } else { "" };
    let _ = writeln!(std::io::stderr(), "{}", skip_line(&case, &format!("{why}{pass}")));
}

#[cfg(test)]
mod tests {
    use super::*;

    // The variables are read per call, as the process has them: each decision is checked
    // against them, so the tests hold in and out of CI.
    #[test]
    fn the_case_is_the_running_tests_name() {
        assert!(current_case().ends_with("the_case_is_the_running_tests_name"), "{}", current_case());
    }

    #[test]
    fn the_line_names_the_case_and_the_reason() {
        assert_eq!(skip_line("oidn::denoises", "pyoidn is missing"), "SKIPPED oidn::denoises: pyoidn is missing");
    }

    #[test]
    fn a_skip_fails_exactly_under_ci() {
        let outcome = std::panic::catch_unwind(|| skip("a reason"));
        assert_eq!(outcome.is_err(), in_ci());
    }

    #[test]
    fn an_unprivileged_case_fails_exactly_in_the_unprivileged_pass() {
        let outcome = std::panic::catch_unwind(|| skip_unless_unprivileged("root ignores 0555"));
        assert_eq!(outcome.is_err(), set(UNPRIVILEGED_VARIABLE));
    }
}
