//! State that belongs to one process and must be made afresh in a forked child: btfrs's rayon
//! thread pool, and (in `btfrs-render`) the GPU device.
//!
//! After `fork()` only the forking thread exists in the child. A rayon pool created by the parent
//! is still there in the child's memory but its worker threads are not, so the child's first
//! parallel call queues work that nobody runs and waits forever; a GPU device's driver threads
//! and file descriptors are likewise the parent's. Python's `multiprocessing` forks by default on
//! Linux before 3.14, so this is the ordinary case for a library called from Python, not an
//! exotic one. Rayon's global pool cannot be rebuilt, so the bindings run all parallel work
//! through [`install`]: in the process that first used btfrs (the one that owns rayon's global
//! pool, see [`claim_global_pool`]) it simply calls the closure, which keeps rayon's global pool
//! and costs nothing; in a process forked from it, it runs the closure in a pool made for that
//! process. (Always using a pool of our own would be simpler but moves every call onto a pool
//! thread: 1.6 us became 25 us for a tiny call, measured.)
//!
//! [`PerProcess`] holds one lazily made value per process. A process tells a stale value from
//! its own by the pid and by a fork counter that a `pthread_atfork` child handler bumps (the
//! counter alone misses forks made before the handler was registered, the pid alone misses a pid
//! reused after the process that made the value exited). A stale value is leaked, never
//! dropped: its threads and handles are not the child's to tear down, and dropping them could
//! wait for threads that do not exist.

use std::marker::PhantomData;
use std::sync::atomic::{AtomicPtr, AtomicU64, Ordering};
use std::sync::{Once, OnceLock};

/// Forks seen by this process and its ancestors since the handler was registered.
static FORKS: AtomicU64 = AtomicU64::new(0);

#[cfg(unix)]
extern "C" fn after_fork_in_child() {
    // Async-signal-safe: one atomic add, no allocation, no lock.
    FORKS.fetch_add(1, Ordering::SeqCst);
}

#[cfg(unix)]
fn register_fork_handler() {
    static ONCE: Once = Once::new();
    extern "C" {
        fn pthread_atfork(
            prepare: Option<extern "C" fn()>,
            parent: Option<extern "C" fn()>,
            child: Option<extern "C" fn()>,
        ) -> std::ffi::c_int;
    }
    // SAFETY: registers a handler with no preconditions that stays valid for the life of the
    // process (a plain function of this library, which is never unloaded while in use). A
    // failure (ENOMEM) only leaves the pid check.
    ONCE.call_once(|| unsafe {
        pthread_atfork(None, None, Some(after_fork_in_child));
    });
}

#[cfg(not(unix))]
fn register_fork_handler() {}

/// Which process (and which fork of it) a value was made in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProcessId {
    pid: u32,
    forks: u64,
}

impl ProcessId {
    /// The calling process.
    pub fn current() -> Self {
        register_fork_handler();
        ProcessId { pid: std::process::id(), forks: FORKS.load(Ordering::SeqCst) }
    }

    /// Whether this is the calling process (false in a child forked after it was taken).
    pub fn is_current(&self) -> bool {
        *self == ProcessId::current()
    }
}

struct Entry<T> {
    owner: ProcessId,
    value: OnceLock<T>,
}

/// One value per process, made on first use in each process (see the module documentation).
///
/// Meant for `static`s: the values of earlier processes and of the current one are never
/// dropped.
pub struct PerProcess<T> {
    current: AtomicPtr<Entry<T>>,
    // Sync and Send exactly when a OnceLock<T> is.
    _value: PhantomData<OnceLock<T>>,
}

impl<T> std::fmt::Debug for PerProcess<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PerProcess").finish_non_exhaustive()
    }
}

impl<T> Default for PerProcess<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T> PerProcess<T> {
    /// Empty in every process.
    pub const fn new() -> Self {
        PerProcess { current: AtomicPtr::new(std::ptr::null_mut()), _value: PhantomData }
    }

    /// This process's value, made by `init` if this process has none yet.
    ///
    /// No lock is shared between processes: a lock held by a thread of the parent at the
    /// moment of the fork (a thread that does not exist in the child) would never be released.
    pub fn get_or_init(&self, init: impl FnOnce() -> T) -> &T {
        let me = ProcessId::current();
        let mut seen = self.current.load(Ordering::Acquire);
        let entry = loop {
            // SAFETY: published entries are never freed (see `PerProcess`).
            if let Some(e) = unsafe { seen.as_ref() } {
                if e.owner == me {
                    break e;
                }
            }
            let fresh = Box::into_raw(Box::new(Entry { owner: me, value: OnceLock::new() }));
            match self.current.compare_exchange(seen, fresh, Ordering::AcqRel, Ordering::Acquire) {
                // The stale entry (if any) is leaked on purpose.
                // SAFETY: `fresh` is now published and never freed.
                Ok(_) => break unsafe { &*fresh },
                Err(now) => {
                    // Another thread of this process published first: use its entry.
                    // SAFETY: `fresh` was never shared.
                    drop(unsafe { Box::from_raw(fresh) });
                    seen = now;
                }
            }
        };
        entry.value.get_or_init(init)
    }
}

static POOL: PerProcess<rayon::ThreadPool> = PerProcess::new();

/// This process's thread pool (rayon's default size: `RAYON_NUM_THREADS`, else one thread per
/// core).
///
/// # Panics
/// If the operating system refuses to start the threads.
pub fn pool() -> &'static rayon::ThreadPool {
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .thread_name(|i| format!("btfrs-{i}"))
            .build()
            .unwrap_or_else(|e| panic!("btfrs could not start its worker threads: {e}"))
    })
}

/// The process whose threads run rayon's global pool (null until claimed). Set once and never
/// changed, so a forked child inherits its parent's claim and knows the global pool is not its.
static GLOBAL_OWNER: AtomicPtr<ProcessId> = AtomicPtr::new(std::ptr::null_mut());

/// Mark the calling process as the owner of rayon's global pool, unless a process (this one or
/// an ancestor it was forked from) already is. Call it before the first parallel work of the
/// program (the Python module does, when it is imported); [`install`] calls it too.
pub fn claim_global_pool() {
    if GLOBAL_OWNER.load(Ordering::Acquire).is_null() {
        let me = Box::into_raw(Box::new(ProcessId::current()));
        if GLOBAL_OWNER.compare_exchange(std::ptr::null_mut(), me, Ordering::AcqRel, Ordering::Acquire).is_err() {
            // SAFETY: `me` was never shared.
            drop(unsafe { Box::from_raw(me) });
        }
    }
}

/// Whether rayon's global pool belongs to the calling process (claiming it if nobody has).
pub fn owns_global_pool() -> bool {
    claim_global_pool();
    // SAFETY: non-null after the claim, and never freed once published.
    unsafe { *GLOBAL_OWNER.load(Ordering::Acquire) }.is_current()
}

/// Run `f` where its rayon calls (`par_iter`, `join`, ...) work in the calling process: on
/// rayon's global pool in the process that owns it, on this process's own [`pool`] in a process
/// forked from it. Panics in `f` propagate to the caller.
pub fn install<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    if owns_global_pool() {
        f()
    } else {
        pool().install(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn one_value_per_process_shared_by_threads() {
        static V: PerProcess<Box<u64>> = PerProcess::new();
        let mut made = 0;
        let a: *const u64 = &**V.get_or_init(|| {
            made += 1;
            Box::new(7)
        });
        let addrs: Vec<usize> = std::thread::scope(|s| {
            let hs: Vec<_> =
                (0..8).map(|_| s.spawn(|| &**V.get_or_init(|| Box::new(8)) as *const u64 as usize)).collect();
            hs.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert_eq!(made, 1);
        assert!(addrs.iter().all(|&p| p == a as usize));
        assert_eq!(**V.get_or_init(|| Box::new(9)), 7);
    }

    #[test]
    fn a_stale_entry_is_replaced() {
        // What a forked child sees: an entry whose owner is another process.
        let v: PerProcess<u32> = PerProcess::new();
        let stale = ProcessId { pid: std::process::id().wrapping_add(1), forks: 0 };
        let e = Box::into_raw(Box::new(Entry { owner: stale, value: OnceLock::from(1) }));
        v.current.store(e, Ordering::SeqCst);
        assert_eq!(*v.get_or_init(|| 2), 2);
        assert_eq!(*v.get_or_init(|| 3), 2);
        assert!(!stale.is_current() && ProcessId::current().is_current());
    }

    #[test]
    fn the_owner_of_the_global_pool_keeps_using_it() {
        assert!(owns_global_pool());
        let names: Vec<Option<String>> =
            install(|| (0..64).into_par_iter().map(|_| std::thread::current().name().map(String::from)).collect());
        assert!(names.iter().flatten().all(|n| !n.starts_with("btfrs-")), "{names:?}");
        assert_eq!(install(|| (1..=100u64).into_par_iter().sum::<u64>()), 5050);
    }

    /// A real fork, in Rust alone: the parent uses the global pool, the child must still finish
    /// parallel work, on a pool of its own. With rayon's global pool in place of `install` the child hangs here (the
    /// alarm kills it: checked).
    #[cfg(target_os = "linux")]
    #[test]
    fn a_forked_child_gets_its_own_pool() {
        extern "C" {
            fn fork() -> i32;
            fn waitpid(pid: i32, status: *mut i32, options: i32) -> i32;
            fn alarm(seconds: u32) -> u32;
            fn _exit(code: i32) -> !;
        }
        assert_eq!(install(|| (0..1000u64).into_par_iter().sum::<u64>()), 499500);
        // SAFETY: the child only runs Rust code that does not rely on other threads' locks
        // (the pool lookup is lock-free), then leaves with _exit; alarm() kills a hung child.
        unsafe {
            let pid = fork();
            assert!(pid >= 0, "fork failed");
            if pid == 0 {
                alarm(20);
                let on_own_pool = install(|| std::thread::current().name().is_some_and(|n| n.starts_with("btfrs-")));
                let ok = !owns_global_pool()
                    && on_own_pool
                    && install(|| (0..1000u64).into_par_iter().sum::<u64>()) == 499500;
                _exit(if ok { 0 } else { 3 });
            }
            let mut status = 0;
            assert_eq!(waitpid(pid, &mut status, 0), pid);
            // Exited normally with code 0 (not killed by SIGALRM).
            assert_eq!(status, 0, "the forked child failed or hung (wait status {status:#x})");
        }
    }
}
