//! Running Rust work from Python: GIL released, Ctrl-C honoured, progress reported, panics caught.
//!
//! Long work runs on a worker thread while the calling thread waits with the GIL released,
//! waking every 100 ms to let Python handle signals (Ctrl-C cancels the work through its
//! [`Monitor`]) and to call the optional `progress(done, total)` callback. No Python code ever
//! runs on a worker or rayon thread.

use crate::errors::{panic_to_py, to_py};
use btfrs_core::{Monitor, Result};
use pyo3::prelude::*;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::mpsc;
use std::time::Duration;

/// Run short work with the GIL released; a panic becomes `InternalError`.
pub fn detach<T: Send>(py: Python<'_>, f: impl FnOnce() -> Result<T> + Send) -> PyResult<T> {
    py.detach(|| catch_unwind(AssertUnwindSafe(f))).map_err(panic_to_py)?.map_err(to_py)
}

/// Run long work on a worker thread, polling for signals and reporting progress.
pub fn monitored<T: Send>(
    py: Python<'_>,
    progress: Option<&Bound<'_, PyAny>>,
    work: impl FnOnce(&Monitor) -> Result<T> + Send,
) -> PyResult<T> {
    let mon = Monitor::new();
    std::thread::scope(|s| {
        let (tx, mut rx) = mpsc::channel();
        let m = &mon;
        s.spawn(move || {
            let r = catch_unwind(AssertUnwindSafe(|| work(m)));
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
