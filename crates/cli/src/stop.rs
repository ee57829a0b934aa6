//! Ctrl-C (SIGINT), SIGTERM and SIGHUP stop a command: they raise its stop flag, and the exit
//! code of a command they stopped follows the signal, by the shell's convention 128 + its
//! number (SIGINT 130, SIGTERM 143, SIGHUP 129), so that a supervisor that sent SIGTERM sees
//! SIGTERM in the code.

use std::process::ExitCode;
use std::sync::atomic::AtomicBool;

/// What a stop that no signal caused (a closed output, a handler that could not be installed)
/// exits with: 128 + SIGINT, what these commands always said for "stopped".
const STOPPED_WITHOUT_A_SIGNAL: u8 = 130;

/// From now on SIGINT, SIGTERM and SIGHUP raise `flag` (one flag a process: a later call
/// replaces the earlier one), and [`exit_code`] names the one caught.
pub fn raise_on_signals(flag: &'static AtomicBool) {
    #[cfg(target_os = "linux")]
    if let Err(e) = ecsync_net::sys::sandbox::catch_termination_signals(flag) {
        // Not fatal: the command runs, only a signal ends it the default way.
        eprintln!("ecsync: warning: cannot catch SIGINT/SIGTERM ({e}); they end it at once");
    }
    #[cfg(not(target_os = "linux"))]
    {
        // A second installation (tests calling twice in one process) is harmless to ignore.
        let _ = ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::Relaxed));
    }
}

/// The exit code of a command a signal stopped: 128 + the signal caught (where the platform
/// tells which), else 130.
pub fn exit_code() -> ExitCode {
    ExitCode::from(code_of(last_signal()))
}

/// 128 + `signal`, or [`STOPPED_WITHOUT_A_SIGNAL`] when none was caught (or one no exit code
/// can carry).
fn code_of(signal: Option<i32>) -> u8 {
    signal
        .and_then(|s| u8::try_from(128 + s).ok())
        .filter(|&c| c > 128)
        .unwrap_or(STOPPED_WITHOUT_A_SIGNAL)
}

#[cfg(target_os = "linux")]
fn last_signal() -> Option<i32> {
    ecsync_net::sys::sandbox::stop_signal().map(|(s, _)| s)
}

#[cfg(not(target_os = "linux"))]
fn last_signal() -> Option<i32> {
    None
}

#[cfg(test)]
mod tests {
    use super::code_of;

    #[test]
    fn the_code_is_128_plus_the_signal_and_130_without_one() {
        assert_eq!(code_of(Some(2)), 130, "SIGINT");
        assert_eq!(code_of(Some(15)), 143, "SIGTERM");
        assert_eq!(code_of(Some(1)), 129, "SIGHUP");
        assert_eq!(code_of(None), 130);
        assert_eq!(code_of(Some(200)), 130, "no exit code carries 328");
    }
}
