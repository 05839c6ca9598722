//! Running Rust work from Python: GIL released, Ctrl-C honoured, progress reported, panics caught,
//! parallel work on this process's own thread pool.
//!
//! Three entries, and every binding goes through one of them:
//! * [`guarded`]: the body of a binding that works with the GIL held (argument conversion,
//!   validation, building results); a panic becomes `InternalError` instead of PyO3's
//!   `PanicException` (a `BaseException` that `except Exception` does not catch).
//! * [`detach`]: short work with the GIL released.
//! * [`monitored`]: long work on a worker thread while the calling thread waits with the GIL
//!   released, waking every 100 ms to let Python handle signals (Ctrl-C cancels the work through
//!   its [`Monitor`]) and to call the optional `progress(done, total)` callback.
//!
//! The last two run their closure in [`btfrs_core::process::install`]: rayon calls inside use
//! rayon's global pool in the process that imported btfrs, and a pool of its own in a child
//! forked from it (Python's `multiprocessing`), where the global pool's threads do not exist.
//! Parallel work must not run outside them (it would hang in such a child). No Python code ever
//! runs on a worker or rayon thread.

use crate::errors::{panic_to_py, to_py};
use btfrs_core::process::install;
use btfrs_core::{Monitor, Result};
use pyo3::prelude::*;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::mpsc;
use std::time::Duration;

/// Run a binding's body, turning a panic into `InternalError` (with the panic's message).
///
/// Wrap the whole body: `fn f(py: Python<'_>, x: ...) -> PyResult<T> { guarded(|| { ... }) }`.
/// [`detach`] and [`monitored`] already guard their closures; `guarded` is for the work done
/// before and after them with the GIL held.
pub fn guarded<T>(f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|p| Err(panic_to_py(p)))
}

/// Run short work with the GIL released, its rayon calls on a pool this process can use; a
/// panic becomes `InternalError`.
pub fn detach<T: Send>(py: Python<'_>, f: impl FnOnce() -> Result<T> + Send) -> PyResult<T> {
    guarded(|| py.detach(|| install(f)).map_err(to_py))
}

/// Run long work on a worker thread, polling for signals and reporting progress.
pub fn monitored<T: Send>(
    py: Python<'_>,
    progress: Option<&Bound<'_, PyAny>>,
    work: impl FnOnce(&Monitor) -> Result<T> + Send,
) -> PyResult<T> {
    guarded(|| run_monitored(py, progress, work))
}

fn run_monitored<T: Send>(
    py: Python<'_>,
    progress: Option<&Bound<'_, PyAny>>,
    work: impl FnOnce(&Monitor) -> Result<T> + Send,
) -> PyResult<T> {
    let mon = Monitor::new();
    std::thread::scope(|s| {
        let (tx, mut rx) = mpsc::channel();
        let m = &mon;
        s.spawn(move || {
            let r = catch_unwind(AssertUnwindSafe(|| install(|| work(m))));
            let _ = tx.send(r);
        });
        loop {
            // The receiver is not Sync, so it moves into the GIL-free closure and back out.
            let (got, back) = py.detach(move || (rx.recv_timeout(Duration::from_millis(100)), rx));
            rx = back;
            let interrupted = py.check_signals().err().or_else(|| {
                let cb = progress?;
                let (done, total) = mon.progress();
                cb.call1((done, total)).err()
            });
            if let Some(e) = interrupted {
                mon.cancel();
                // Wait for the worker to notice (it checks between chunks), then re-raise.
                let _ = py.detach(move || rx.recv());
                return Err(e);
            }
            match got {
                Ok(r) => {
                    if let Some(cb) = progress {
                        let (_, total) = mon.progress();
                        cb.call1((total, total))?;
                    }
                    return r.map_err(panic_to_py)?.map_err(to_py);
                }
                Err(mpsc::RecvTimeoutError::Timeout) => continue,
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    return Err(crate::errors::InternalError::new_err("worker thread vanished"))
                }
            }
        }
    })
}

/// Test hook (not public API): panic where `place` says: "held" (GIL held, in [`guarded`]),
/// "detached" (in [`detach`]), "monitored" (on the worker of [`monitored`]) or "parallel" (on
/// a rayon thread, inside [`detach`]), so the tests can check that every path raises
/// `InternalError`.
#[pyfunction]
pub fn _panic_for_test(py: Python<'_>, place: &str) -> PyResult<()> {
    let boom = || -> Result<()> { panic!("test panic ({place})") };
    match place {
        "held" => guarded(|| boom().map_err(to_py)),
        "detached" => detach(py, boom),
        "monitored" => monitored(py, None, |_| boom()),
        "parallel" => detach(py, || {
            use rayon::prelude::*;
            (0..64u32).into_par_iter().for_each(|i| assert!(i != 37, "test panic (parallel)"));
            Ok(())
        }),
        other => {
            Err(crate::errors::arg("place", format!("expected held, detached, monitored or parallel, got {other:?}")))
        }
    }
}
