//! Clean stop on SIGINT/SIGTERM: the handler only sets a flag; the runs poll it once per step
//! (through [`StopOnInterrupt`], a recorder) and end with [`CliError::Interrupted`], so that the
//! temporary files of unfinished results are removed (their writers' `Drop`) and the command
//! can say what was completed before exiting 130.

use crate::error::CliError;
use exompc::sim::{Recorder, StepRecord};
use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

#[cfg(unix)]
extern "C" fn on_signal(_sig: libc::c_int) {
    // Only an atomic store: async-signal-safe.
    REQUESTED.store(true, Ordering::SeqCst);
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
    REQUESTED.load(Ordering::SeqCst)
}

/// `Err(CliError::Interrupted)` once a stop was requested.
pub fn check(what: &str) -> Result<(), CliError> {
    if requested() {
        Err(CliError::Interrupted(format!("interrupted: {what}")))
    } else {
        Ok(())
    }
}

/// A recorder that ends the run (with an `Interrupted` I/O error) once a stop was requested.
pub struct StopOnInterrupt;

impl<const N: usize> Recorder<N> for StopOnInterrupt {
    fn record(&mut self, _r: &StepRecord<'_, N>) -> std::io::Result<()> {
        if requested() {
            Err(std::io::Error::new(
                std::io::ErrorKind::Interrupted,
                "interrupted by a signal",
            ))
        } else {
            Ok(())
        }
    }
}
