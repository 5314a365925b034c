//! Clean stop on SIGINT/SIGTERM: the handler only records the signal; the runs poll it once per
//! control step (through [`stop_on_interrupt`], a recorder that ends the run early with its
//! results so far) and the command ends with [`CliError::Interrupted`] after keeping what was
//! completed (marked partial), exiting 130 after SIGINT and 143 after SIGTERM.

use crate::error::{CliError, SIGNAL};
use exompc::sim::StopWhen;
use std::sync::atomic::Ordering;

#[cfg(unix)]
extern "C" fn on_signal(sig: libc::c_int) {
    // Only an atomic store: async-signal-safe.
    SIGNAL.store(sig, Ordering::SeqCst);
}

/// Installs the SIGINT/SIGTERM handler (Unix; elsewhere the default behaviour stays).
pub fn install() {
    #[cfg(unix)]
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        let h = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::signal(libc::SIGINT, h);
        libc::signal(libc::SIGTERM, h);
    }
}

/// True once SIGINT or SIGTERM arrived.
pub fn requested() -> bool {
    SIGNAL.load(Ordering::SeqCst) != 0
}

/// The exit code after the signal received: 128 + its number (130 for SIGINT, 143 for
/// SIGTERM), as a shell reports a process killed by it; 130 when none was recorded.
pub fn exit_code() -> u8 {
    crate::error::interrupted_exit_code()
}

/// The name of the signal received (`SIGINT`, `SIGTERM`), for messages.
pub fn signal_name() -> &'static str {
    #[cfg(unix)]
    if SIGNAL.load(Ordering::SeqCst) == libc::SIGTERM {
        return "SIGTERM";
    }
    "SIGINT"
}

/// `Err(CliError::Interrupted)` once a stop was requested.
pub fn check(what: &str) -> Result<(), CliError> {
    if requested() {
        Err(CliError::Interrupted(format!("interrupted: {what}")))
    } else {
        Ok(())
    }
}

/// A recorder that ends the run once a stop was requested (the library's
/// [`exompc::sim::StopWhen`] on [`requested`]: the run returns its summary so far).
/// Put it after the recorders that must see the last step (the trace), so that they and the
/// summary agree.
pub fn stop_on_interrupt() -> StopWhen<fn() -> bool> {
    StopWhen(requested)
}

/// Runs `f` on a helper thread, returning its result, or `Err(Interrupted)` within about
/// 50 ms of a stop request (the helper is abandoned; the process is about to exit). For the
/// set-up computations a command cannot poll inside (e.g. the multi-stage identifiability
/// check, long with a tiny `timing.dt`).
pub fn interruptible<T: Send + 'static>(
    what: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, CliError> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    loop {
        match rx.recv_timeout(std::time::Duration::from_millis(50)) {
            Ok(v) => return Ok(v),
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => check(what)?,
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                return Err(CliError::Runtime(format!("{what}: the computation failed")))
            }
        }
    }
}
