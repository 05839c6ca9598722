//! Progress, cancellation and a memory budget for long work.
//!
//! Long functions take a `&Monitor`: they add to its counter as they go and stop with
//! [`crate::Error::Interrupted`] once it is cancelled. A caller may also give it a memory limit
//! ([`Monitor::set_memory_limit`]): the anonymous memory the work may allocate besides its
//! result, which the out-of-core fits (memory-mapped BTFs larger than RAM) size their chunks
//! by. The Python layer runs the work on a worker
//! thread and polls the monitor from the main thread, so Ctrl-C and progress bars work while the
//! GIL is released and no Python callback ever runs on a rayon thread.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Shared progress counter and cancel flag.
#[derive(Debug, Default)]
pub struct Monitor {
    done: AtomicU64,
    total: AtomicU64,
    cancelled: AtomicBool,
    /// Bytes; 0 = no limit.
    memory_limit: AtomicU64,
}

impl Monitor {
    /// A monitor nobody watches (for Rust callers and benches).
    pub fn new() -> Self {
        Self::default()
    }

    /// Announce the total amount of work (in any unit) and reset the counter.
    pub fn start(&self, total: u64) {
        self.total.store(total, Ordering::Relaxed);
        self.done.store(0, Ordering::Relaxed);
    }

    /// Change the total, keeping the counter (work found shorter or longer than announced).
    pub fn set_total(&self, total: u64) {
        self.total.store(total, Ordering::Relaxed);
    }

    /// Add `n` units of finished work.
    #[inline]
    pub fn advance(&self, n: u64) {
        self.done.fetch_add(n, Ordering::Relaxed);
    }

    /// (done, total) so far.
    pub fn progress(&self) -> (u64, u64) {
        (self.done.load(Ordering::Relaxed), self.total.load(Ordering::Relaxed))
    }

    /// Ask the work to stop at its next check.
    pub fn cancel(&self) {
        self.cancelled.store(true, Ordering::Relaxed);
    }

    /// Limit the anonymous memory the work may allocate besides its result to `bytes` (`None`:
    /// no limit, the default). Work that cannot stay within it fails with an error naming
    /// `memory_limit` and the least it needs, before it allocates.
    pub fn set_memory_limit(&self, bytes: Option<u64>) {
        self.memory_limit.store(bytes.unwrap_or(0), Ordering::Relaxed);
    }

    /// The limit of [`Monitor::set_memory_limit`].
    pub fn memory_limit(&self) -> Option<u64> {
        match self.memory_limit.load(Ordering::Relaxed) {
            0 => None,
            b => Some(b),
        }
    }

    /// Whether [`Monitor::cancel`] was called.
    #[inline]
    pub fn is_cancelled(&self) -> bool {
        self.cancelled.load(Ordering::Relaxed)
    }

    /// `Err(Interrupted)` once cancelled, for `?` at chunk boundaries.
    #[inline]
    pub fn check(&self) -> crate::Result<()> {
        if self.is_cancelled() {
            Err(crate::Error::Interrupted)
        } else {
            Ok(())
        }
    }
}
