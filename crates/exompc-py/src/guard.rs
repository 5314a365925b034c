//! The boundary between Python and Rust: a Rust panic becomes a `RuntimeError` (never a
//! `PanicException`), long runs poll Ctrl-C from the calling thread and can be cancelled with
//! a `CancelToken`, and file errors become `OSError` subclasses with `errno` and `filename`.

use pyo3::exceptions::{PyOSError, PyRuntimeError};
use pyo3::prelude::*;
use std::any::Any;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// How often a long call wakes up to run Python's signal handlers (Ctrl-C).
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// Runs the body of a Python entry point, turning a Rust panic into a `RuntimeError`.
pub fn catch<T>(f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|p| Err(panic_error(p.as_ref())))
}

/// A `RuntimeError` carrying a panic's message.
fn panic_error(p: &(dyn Any + Send)) -> PyErr {
    let msg = p
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".to_string());
    PyRuntimeError::new_err(format!(
        "internal error in exompc (a bug, please report it): {msg}"
    ))
}

/// An `OSError` for a failed file operation: `OSError(errno, "<what>: <reason>", path)`, which
/// Python turns into the matching subclass (`FileNotFoundError`, `PermissionError`,
/// `IsADirectoryError`, ...) with `errno` and `filename` set; its text reads
/// `[Errno 13] cannot save scenario to: Permission denied: '/path'`.
pub fn os_error(what: &str, path: &Path, e: &std::io::Error) -> PyErr {
    let shown = path.display().to_string();
    match e.raw_os_error() {
        Some(code) => {
            // The OS's own text, without the " (os error N)" that Rust appends.
            let full = e.to_string();
            let reason = full
                .strip_suffix(&format!(" (os error {code})"))
                .unwrap_or(&full);
            PyOSError::new_err((code, format!("{what}: {reason}"), shown))
        }
        None => PyOSError::new_err(format!("{what} {shown}: {e}")),
    }
}

/// Raises a Rust panic (with the GIL held, or inside a run's helper thread when `in_run`), to
/// test that the boundary turns it into `RuntimeError`. Not part of the API.
#[pyfunction]
#[pyo3(signature = (message, in_run = false))]
pub fn _raise_panic(py: Python<'_>, message: &str, in_run: bool) -> PyResult<()> {
    catch(|| {
        if in_run {
            interruptible(py, None, |_| -> () { panic!("{message}") })?;
            Ok(())
        } else {
            panic!("{message}")
        }
    })
}

/// `exompc.CancelToken`: stops the long calls it is passed to (``simulate``, ``run_many``,
/// ``envelope``, ``montecarlo``) between two control steps, from any thread.
///
/// ``token = CancelToken()``; ``simulate(s, cancel=token)`` in one thread,
/// ``token.cancel()`` in another: the call raises ``RunError("... cancelled ...")`` within one
/// control step. A cancelled token stays cancelled.
#[pyclass(module = "exompc", name = "CancelToken", frozen)]
pub struct CancelToken {
    pub flag: Arc<AtomicBool>,
}

#[pymethods]
impl CancelToken {
    #[new]
    fn new() -> Self {
        CancelToken {
            flag: Arc::new(AtomicBool::new(false)),
        }
    }

    /// Asks every call holding this token to stop (thread-safe, returns at once).
    fn cancel(&self) {
        self.flag.store(true, Ordering::SeqCst);
    }

    /// Whether ``cancel()`` was called.
    #[getter]
    fn cancelled(&self) -> bool {
        self.flag.load(Ordering::SeqCst)
    }

    fn __repr__(&self) -> String {
        format!(
            "CancelToken(cancelled={})",
            if self.cancelled() { "True" } else { "False" }
        )
    }
}

/// How an interruptible call ended without a Python exception.
pub enum Outcome<T> {
    /// The work finished (its own result may still be an error).
    Done(T),
    /// The `CancelToken` was cancelled (the work's result is discarded).
    Cancelled,
}

/// Runs `work` on a helper thread with the GIL released while the calling thread waits,
/// waking every [`SIGNAL_POLL`] to run Python's signal handlers. When a handler raises (Ctrl-C:
/// `KeyboardInterrupt`), `work`'s stop flag is raised, the helper ends between two control
/// steps, and that exception is returned; the process stays usable. `work` polls `stop()`
/// (it also turns true when `cancel` is cancelled). A panic in `work` becomes `RuntimeError`.
///
/// Signal handlers only run on Python's main thread, so from another thread only `cancel`
/// stops the work.
pub fn interruptible<T: Send>(
    py: Python<'_>,
    cancel: Option<&CancelToken>,
    work: impl FnOnce(&(dyn Fn() -> bool + Sync)) -> T + Send,
) -> PyResult<Outcome<T>> {
    let interrupted = AtomicBool::new(false);
    let token = cancel.map(|c| Arc::clone(&c.flag));
    let is_cancelled = || token.as_ref().is_some_and(|f| f.load(Ordering::Relaxed));
    let stop = || interrupted.load(Ordering::Relaxed) || is_cancelled();
    let done = AtomicBool::new(false);
    let waiter = std::thread::current();
    let result = std::thread::scope(|sc| {
        let (stop, done, waiter) = (&stop, &done, &waiter);
        let spawned = std::thread::Builder::new()
            .name("exompc-run".into())
            .spawn_scoped(sc, move || {
                let r = catch_unwind(AssertUnwindSafe(|| work(stop)));
                done.store(true, Ordering::SeqCst);
                waiter.unpark();
                r
            });
        let handle = match spawned {
            Ok(h) => h,
            Err(e) => {
                return Err(PyRuntimeError::new_err(format!(
                    "cannot start the run's thread: {e}"
                )))
            }
        };
        let mut raised = None;
        while !done.load(Ordering::SeqCst) {
            py.detach(|| std::thread::park_timeout(SIGNAL_POLL));
            if done.load(Ordering::SeqCst) {
                break;
            }
            if let Err(e) = py.check_signals() {
                interrupted.store(true, Ordering::SeqCst);
                raised = Some(e);
                break;
            }
        }
        let joined = py.detach(|| handle.join());
        if let Some(e) = raised {
            return Err(e);
        }
        match joined {
            Ok(Ok(r)) => Ok(r),
            Ok(Err(p)) | Err(p) => Err(panic_error(p.as_ref())),
        }
    })?;
    Ok(if is_cancelled() {
        Outcome::Cancelled
    } else {
        Outcome::Done(result)
    })
}
