//! Intra-step parallelism: the step (network and solver alike) splits its loops into independent
//! tasks and hands them to an [`Executor`]. An engine plugs in its job system (through the C ABI too);
//! without one the step runs serially, and under `std` `ThreadPool` offers persistent worker
//! threads that run a step's tasks without allocating.

/// Runs the independent tasks of a step.
///
/// # Safety
/// The step gives each task index its own part of its buffers, so an implementor must keep this
/// contract (nothing checks it, and breaking it creates aliasing mutable references):
/// [`run`](Executor::run) calls `task(i)` exactly once for every `i` in `0..n` (never twice,
/// never an index outside `0..n`), from any threads, and returns only after every call has
/// returned. A task that panics may end `run` by unwinding, after the other calls returned.
pub unsafe trait Executor: Send + Sync {
    /// How many tasks are worth splitting work into (at least 1).
    fn parallelism(&self) -> usize;
    /// Calls `task(i)` once for each `i in 0..n` and returns when all calls are done.
    fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync));
}

/// Runs every task on the calling thread, in order.
#[derive(Clone, Copy, Debug, Default)]
pub struct Serial;

// SAFETY: every index once, in order, on the calling thread.
unsafe impl Executor for Serial {
    fn parallelism(&self) -> usize {
        1
    }
    fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
        for i in 0..n {
            task(i);
        }
    }
}

pub(crate) mod par;

#[cfg(feature = "std")]
pub use pool::ThreadPool;

#[cfg(feature = "std")]
mod pool {
    use super::Executor;
    use core::any::Any;
    use core::cell::UnsafeCell;
    use std::boxed::Box;
    use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
    use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
    use std::sync::{Arc, Condvar, Mutex, TryLockError};
    use std::thread::JoinHandle;
    use std::time::{Duration, Instant};
    use std::vec::Vec;

    type Task = &'static (dyn Fn(usize) + Sync);

    /// How long an idle worker spins for the next job before it sleeps. A training step hands
    /// out about 1,600 jobs, microseconds apart: waking a sleeping thread costs more than most
    /// of them take, and at h = 32 the hand-offs were the largest serial cost of the step.
    const SPIN: Duration = Duration::from_micros(200);

    /// A claim word packs the job number (16 bits, wrapping), the job's task count and the next
    /// task index (24 bits each), so that one atomic add both claims a task and says whether the
    /// claim is valid, without reading anything a later job may overwrite.
    const FIELD: u32 = 24;
    const MASK: u64 = (1 << FIELD) - 1;
    /// Most tasks per job (the index must not carry into the count even after every thread has
    /// over-claimed once); larger jobs run in rounds.
    const MAX_TASKS: usize = (1 << FIELD) - 4096;

    fn word(job: u64, n: usize) -> u64 {
        ((job & 0xffff) << (2 * FIELD)) | ((n as u64) << FIELD)
    }

    fn job_of(w: u64) -> u64 {
        w >> (2 * FIELD)
    }

    struct Shared {
        /// Job number, task count and next unclaimed task index (see [`word`]). A valid claim
        /// (index below the count) keeps its job's task alive: the caller does not return before
        /// every claimed task has finished.
        claim: AtomicU64,
        /// The current job's task, written by the caller before it publishes the job in `claim`
        /// (release) and read only under a valid claim (acquired), while the job cannot end.
        task: UnsafeCell<Option<Task>>,
        /// Tasks of the current job finished.
        done: AtomicUsize,
        /// Workers asleep (or about to sleep) on `wake`.
        sleepers: AtomicUsize,
        shutdown: AtomicBool,
        lock: Mutex<()>,
        wake: Condvar,
        /// The payload of the first task of the current job that panicked, if one did: the
        /// caller re-raises it once every task of the job has finished.
        panic: Mutex<Option<Box<dyn Any + Send>>>,
        /// Workers that have started running [`worker`]: the standard library's own start-up of
        /// a thread (its name copied for the stack-overflow handler) allocates, and must be over
        /// before the pool is used, or it would land inside the first job.
        started: AtomicUsize,
    }

    // SAFETY: `task` is written only by the thread running `Executor::run` (one at a time: `run`
    // holds `caller`) while no valid claim of the previous job is outstanding, and read only under
    // a valid claim, ordered by the release store and acquiring adds on `claim`.
    unsafe impl Sync for Shared {}
    unsafe impl Send for Shared {}

    /// Persistent worker threads (created once); [`Executor::run`] shares a job's tasks between
    /// them and the calling thread. Running a job allocates nothing and, while the workers are
    /// still spinning from the previous job, takes no lock.
    pub struct ThreadPool {
        shared: Arc<Shared>,
        /// Serialises callers: a pool runs one job at a time.
        caller: Mutex<()>,
        workers: Vec<JoinHandle<()>>,
    }

    impl core::fmt::Debug for ThreadPool {
        fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            write!(f, "ThreadPool({} threads)", self.workers.len() + 1)
        }
    }

    /// Runs task `i` of the current job and counts it done.
    ///
    /// # Safety
    /// The caller holds a valid claim of task `i`, or is the job's own caller (which wrote
    /// `task`) running the task 0 it kept for itself.
    unsafe fn run_task(s: &Shared, i: usize) {
        // SAFETY: by the contract (see `Shared::task`).
        if let Some(t) = unsafe { *s.task.get() } {
            // A panicking task must still count as done: otherwise the caller would wait
            // forever (or, unwinding, leave workers running a task whose captures are gone).
            if let Err(payload) = catch_unwind(AssertUnwindSafe(|| t(i))) {
                let mut first = s.panic.lock().unwrap_or_else(|e| e.into_inner());
                first.get_or_insert(payload);
            }
        }
        s.done.fetch_add(1, Ordering::Release);
    }

    /// Claims and runs tasks until a claim comes back invalid; returns that claim's job number.
    /// Claims may move on to jobs published meanwhile.
    fn claim(s: &Shared) -> u64 {
        loop {
            let w = s.claim.fetch_add(1, Ordering::AcqRel);
            let (n, i) = ((w >> FIELD) & MASK, w & MASK);
            if i >= n {
                return job_of(w);
            }
            // SAFETY: a valid claim of task `i`.
            unsafe { run_task(s, i as usize) };
        }
    }

    fn worker(s: &Shared) {
        s.started.fetch_add(1, Ordering::Release);
        let mut seen = job_of(s.claim.load(Ordering::Acquire));
        loop {
            // Spin, then sleep, until a new job is published.
            let start = Instant::now();
            let mut spins = 0u32;
            loop {
                if job_of(s.claim.load(Ordering::Acquire)) != seen || s.shutdown.load(Ordering::Acquire) {
                    break;
                }
                spins = spins.wrapping_add(1);
                if !spins.is_multiple_of(64) || start.elapsed() < SPIN {
                    core::hint::spin_loop();
                    continue;
                }
                let mut guard = s.lock.lock().unwrap_or_else(|e| e.into_inner());
                s.sleepers.fetch_add(1, Ordering::SeqCst);
                while job_of(s.claim.load(Ordering::SeqCst)) == seen && !s.shutdown.load(Ordering::SeqCst) {
                    guard = s.wake.wait(guard).unwrap_or_else(|e| e.into_inner());
                }
                s.sleepers.fetch_sub(1, Ordering::SeqCst);
            }
            if s.shutdown.load(Ordering::Acquire) {
                return;
            }
            seen = claim(s);
        }
    }

    impl ThreadPool {
        /// A pool running jobs on `threads` threads in all: the caller plus `threads - 1`
        /// workers. When the operating system refuses a thread, the pool keeps the workers it
        /// has ([`threads`](Self::threads) says how many in all).
        pub fn new(threads: usize) -> ThreadPool {
            let shared = Arc::new(Shared {
                claim: AtomicU64::new(0),
                task: UnsafeCell::new(None),
                done: AtomicUsize::new(0),
                sleepers: AtomicUsize::new(0),
                shutdown: AtomicBool::new(false),
                lock: Mutex::new(()),
                wake: Condvar::new(),
                panic: Mutex::new(None),
                started: AtomicUsize::new(0),
            });
            let mut workers = Vec::new();
            for k in 1..threads.max(1) {
                let s = Arc::clone(&shared);
                match std::thread::Builder::new().name(std::format!("hood-worker-{k}")).spawn(move || worker(&s)) {
                    Ok(handle) => workers.push(handle),
                    Err(_) => break,
                }
            }
            while shared.started.load(Ordering::Acquire) < workers.len() {
                std::thread::yield_now();
            }
            ThreadPool { shared, caller: Mutex::new(()), workers }
        }

        /// Threads in all (workers plus the caller).
        pub fn threads(&self) -> usize {
            self.workers.len() + 1
        }
    }

    // SAFETY: each index is claimed once from a shared counter and `run` waits for every
    // claimed task to finish before it returns (see `run` below).
    unsafe impl Executor for ThreadPool {
        fn parallelism(&self) -> usize {
            self.threads()
        }

        fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
            // One job at a time: a nested or concurrent call runs its tasks on its own thread.
            let one_job = match self.caller.try_lock() {
                Ok(g) => Some(g),
                Err(TryLockError::Poisoned(p)) => Some(p.into_inner()),
                Err(TryLockError::WouldBlock) => None,
            };
            if self.workers.is_empty() || n <= 1 || one_job.is_none() {
                (0..n).for_each(task);
                return;
            }
            if n > MAX_TASKS {
                for start in (0..n).step_by(MAX_TASKS) {
                    let m = MAX_TASKS.min(n - start);
                    self.run_job(m, &|i| task(start + i));
                }
            } else {
                self.run_job(n, task);
            }
        }
    }

    impl ThreadPool {
        fn run_job(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
            // SAFETY: the reference is extended to 'static only while this call runs: a worker
            // calls it only under a valid claim of this job, and this function returns only
            // after every claimed task has finished (`done == n`); the next job replaces it.
            let task_static: Task = unsafe { core::mem::transmute::<&(dyn Fn(usize) + Sync), Task>(task) };
            let s = &*self.shared;
            let job = job_of(s.claim.load(Ordering::Relaxed)) + 1;
            // SAFETY: no valid claim of the previous job is outstanding (its caller saw
            // `done == n`), so no thread reads `task` now.
            unsafe { *s.task.get() = Some(task_static) };
            s.done.store(0, Ordering::Relaxed);
            // Workers claim from task 1; task 0 is the caller's. With one task per thread, jobs
            // split alike then give each thread the same rows every time, which stay in its
            // core's caches (a shared claim for task 0 gave it to whichever thread came first).
            s.claim.store(word(job, n) | 1, Ordering::SeqCst);
            if s.sleepers.load(Ordering::SeqCst) > 0 {
                let _g = s.lock.lock().unwrap_or_else(|e| e.into_inner());
                s.wake.notify_all();
            }
            // SAFETY: this thread wrote `task` for this job; task 0 is claimed by no one else.
            unsafe { run_task(s, 0) };
            claim(s);
            // The last tasks may still run on workers: spin, then yield.
            let mut spins = 0u32;
            while s.done.load(Ordering::Acquire) < n {
                spins = spins.wrapping_add(1);
                if spins < 1 << 12 {
                    core::hint::spin_loop();
                } else {
                    std::thread::yield_now();
                }
            }
            // Every task has finished: a panic in one of them goes on in the caller, as it
            // would have without the pool.
            let payload = s.panic.lock().unwrap_or_else(|e| e.into_inner()).take();
            if let Some(payload) = payload {
                resume_unwind(payload);
            }
        }
    }

    impl Drop for ThreadPool {
        fn drop(&mut self) {
            {
                let _g = self.shared.lock.lock().unwrap_or_else(|e| e.into_inner());
                self.shared.shutdown.store(true, Ordering::SeqCst);
                self.shared.wake.notify_all();
            }
            for w in self.workers.drain(..) {
                let _ = w.join();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::sync::atomic::{AtomicUsize, Ordering};

    /// A task that panics, on a worker or on the caller, ends the job as a panic in the caller
    /// once every other task has run (no hang, no task left running), and the pool goes on.
    #[cfg(feature = "std")]
    #[test]
    fn sim_thread_pool_passes_task_panics_to_the_caller() {
        let pool = ThreadPool::new(3);
        for round in 0..40usize {
            let n = 2 + round % 7;
            let bad = round % n;
            let hits: alloc::vec::Vec<AtomicUsize> = (0..n).map(|_| AtomicUsize::new(0)).collect();
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                pool.run(n, &|i| {
                    hits[i].fetch_add(1, Ordering::Relaxed);
                    if i == bad {
                        std::panic::panic_any(round);
                    }
                })
            }));
            let payload = outcome.expect_err("the task's panic reaches the caller");
            assert_eq!(payload.downcast_ref::<usize>(), Some(&round));
            assert!(hits.iter().all(|h| h.load(Ordering::Relaxed) == 1), "round {round}");
            let sum = AtomicUsize::new(0);
            pool.run(n, &|i| {
                sum.fetch_add(i, Ordering::Relaxed);
            });
            assert_eq!(sum.load(Ordering::Relaxed), n * (n - 1) / 2);
        }
    }

    /// Task 0 of every job runs on the calling thread, so jobs split alike keep each thread on
    /// the same rows. Before, the caller and a spinning worker raced for it.
    #[cfg(feature = "std")]
    #[test]
    fn sim_thread_pool_keeps_task_zero_on_the_caller() {
        let pool = ThreadPool::new(2);
        let caller = std::thread::current().id();
        let elsewhere = AtomicUsize::new(0);
        for round in 0..2000usize {
            pool.run(2, &|i| {
                if i == 0 && std::thread::current().id() != caller {
                    elsewhere.fetch_add(1, Ordering::Relaxed);
                }
                // Long enough for the other thread to claim while this one works.
                let t = std::time::Instant::now();
                while t.elapsed() < std::time::Duration::from_micros(2) {
                    core::hint::spin_loop();
                }
            });
            if round % 500 == 499 {
                // Jobs after the worker fell asleep, too.
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
        }
        assert_eq!(elsewhere.load(Ordering::Relaxed), 0, "jobs whose task 0 ran off the calling thread");
    }

    #[cfg(feature = "std")]
    #[test]
    fn sim_thread_pool_runs_every_task_once() {
        let pool = ThreadPool::new(3);
        for n in [0usize, 1, 2, 7, 100] {
            let hits: alloc::vec::Vec<AtomicUsize> = (0..n).map(|_| AtomicUsize::new(0)).collect();
            pool.run(n, &|i| {
                hits[i].fetch_add(1, Ordering::Relaxed);
            });
            assert!(hits.iter().all(|h| h.load(Ordering::Relaxed) == 1));
        }
        // Many short jobs back to back (the workers spin between them), jobs after the workers
        // fell asleep, a nested call (runs on its own thread) and jobs from several callers.
        let pool = std::sync::Arc::new(ThreadPool::new(3));
        let total = AtomicUsize::new(0);
        for round in 0..2000usize {
            let n = 1 + round % 9;
            let hits: alloc::vec::Vec<AtomicUsize> = (0..n).map(|_| AtomicUsize::new(0)).collect();
            pool.run(n, &|i| {
                hits[i].fetch_add(1, Ordering::Relaxed);
                total.fetch_add(1, Ordering::Relaxed);
            });
            assert!(hits.iter().all(|h| h.load(Ordering::Relaxed) == 1), "round {round}");
            if round % 500 == 499 {
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
        }
        assert_eq!(total.load(Ordering::Relaxed), (0..2000).map(|r| 1 + r % 9).sum::<usize>());
        let nested = AtomicUsize::new(0);
        pool.run(4, &|_| {
            pool.run(3, &|_| {
                nested.fetch_add(1, Ordering::Relaxed);
            })
        });
        assert_eq!(nested.load(Ordering::Relaxed), 12);
        let threads: alloc::vec::Vec<_> = (0..3)
            .map(|_| {
                let p = std::sync::Arc::clone(&pool);
                std::thread::spawn(move || {
                    let sum = AtomicUsize::new(0);
                    for _ in 0..300 {
                        p.run(5, &|i| {
                            sum.fetch_add(i, Ordering::Relaxed);
                        });
                    }
                    sum.load(Ordering::Relaxed)
                })
            })
            .collect();
        for t in threads {
            assert_eq!(t.join().unwrap(), 300 * 10);
        }
        assert_eq!(ThreadPool::new(0).threads(), 1);
        let sum = AtomicUsize::new(0);
        Serial.run(5, &|i| {
            sum.fetch_add(i, Ordering::Relaxed);
        });
        assert_eq!(sum.load(Ordering::Relaxed), 10);
    }
}
