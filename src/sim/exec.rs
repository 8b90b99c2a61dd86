//! Intra-step parallelism: the step splits its row and edge loops into independent tasks and
//! hands them to an [`Executor`]. An engine plugs in its job system (through the C ABI too);
//! without one the step runs serially, and under `std` [`ThreadPool`] offers persistent worker
//! threads that run a step's tasks without allocating.

/// Runs the independent tasks of a step.
///
/// # Safety contract for implementors (checked by nothing, relied on by the step)
/// [`run`](Executor::run) must call `task(i)` exactly once for every `i` in `0..n`, from any
/// threads, and return only after every call has returned.
pub trait Executor: Send + Sync {
    /// How many tasks are worth splitting work into (at least 1).
    fn parallelism(&self) -> usize;
    /// Calls `task(i)` once for each `i in 0..n` and returns when all calls are done.
    fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync));
}

/// Runs every task on the calling thread, in order.
#[derive(Clone, Copy, Debug, Default)]
pub struct Serial;

impl Executor for Serial {
    fn parallelism(&self) -> usize {
        1
    }
    fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
        for i in 0..n {
            task(i);
        }
    }
}

#[cfg(feature = "std")]
pub use pool::ThreadPool;

#[cfg(feature = "std")]
mod pool {
    use super::Executor;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::{Arc, Condvar, Mutex};
    use std::thread::JoinHandle;
    use std::vec::Vec;

    type Task = &'static (dyn Fn(usize) + Sync);

    struct Job {
        generation: u64,
        task: Option<Task>,
        n: usize,
        /// Workers currently inside the job.
        running: usize,
        shutdown: bool,
    }

    struct Shared {
        job: Mutex<Job>,
        wake: Condvar,
        idle: Condvar,
        next: AtomicUsize,
        done: AtomicUsize,
    }

    /// Persistent worker threads (created once); [`Executor::run`] shares a job's tasks between
    /// them and the calling thread. Running a job allocates nothing.
    pub struct ThreadPool {
        shared: Arc<Shared>,
        workers: Vec<JoinHandle<()>>,
    }

    impl core::fmt::Debug for ThreadPool {
        fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            write!(f, "ThreadPool({} threads)", self.workers.len() + 1)
        }
    }

    fn claim(shared: &Shared, task: Task, n: usize) {
        loop {
            let i = shared.next.fetch_add(1, Ordering::Relaxed);
            if i >= n {
                break;
            }
            task(i);
            shared.done.fetch_add(1, Ordering::Release);
        }
    }

    impl ThreadPool {
        /// A pool running jobs on `threads` threads in all: the caller plus `threads - 1`
        /// workers.
        pub fn new(threads: usize) -> ThreadPool {
            let shared = Arc::new(Shared {
                job: Mutex::new(Job { generation: 0, task: None, n: 0, running: 0, shutdown: false }),
                wake: Condvar::new(),
                idle: Condvar::new(),
                next: AtomicUsize::new(0),
                done: AtomicUsize::new(0),
            });
            let workers = (1..threads.max(1))
                .map(|_| {
                    let s = Arc::clone(&shared);
                    std::thread::spawn(move || {
                        let mut seen = 0u64;
                        loop {
                            let (task, n) = {
                                let mut job = s.job.lock().unwrap_or_else(|e| e.into_inner());
                                while !job.shutdown && (job.generation == seen || job.task.is_none()) {
                                    job = s.wake.wait(job).unwrap_or_else(|e| e.into_inner());
                                }
                                if job.shutdown {
                                    return;
                                }
                                seen = job.generation;
                                job.running += 1;
                                (job.task, job.n)
                            };
                            if let Some(t) = task {
                                claim(&s, t, n);
                            }
                            let mut job = s.job.lock().unwrap_or_else(|e| e.into_inner());
                            job.running -= 1;
                            s.idle.notify_all();
                        }
                    })
                })
                .collect();
            ThreadPool { shared, workers }
        }

        /// Threads in all (workers plus the caller).
        pub fn threads(&self) -> usize {
            self.workers.len() + 1
        }
    }

    impl Executor for ThreadPool {
        fn parallelism(&self) -> usize {
            self.threads()
        }

        fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
            if self.workers.is_empty() || n <= 1 {
                (0..n).for_each(task);
                return;
            }
            // SAFETY: the reference is extended to 'static only while this call runs: workers
            // take it under the mutex while `job.task` is set, and this function clears it and
            // waits (under the same mutex) until no worker is inside the job before returning,
            // so no worker can call it after `task`'s real lifetime ends.
            let task_static: Task = unsafe { core::mem::transmute::<&(dyn Fn(usize) + Sync), Task>(task) };
            let s = &*self.shared;
            {
                let mut job = s.job.lock().unwrap_or_else(|e| e.into_inner());
                s.next.store(0, Ordering::Relaxed);
                s.done.store(0, Ordering::Relaxed);
                job.generation += 1;
                job.task = Some(task_static);
                job.n = n;
                s.wake.notify_all();
            }
            claim(s, task_static, n);
            let mut job = s.job.lock().unwrap_or_else(|e| e.into_inner());
            while s.done.load(Ordering::Acquire) < n || job.running > 0 {
                job = s.idle.wait(job).unwrap_or_else(|e| e.into_inner());
            }
            job.task = None;
        }
    }

    impl Drop for ThreadPool {
        fn drop(&mut self) {
            {
                let mut job = self.shared.job.lock().unwrap_or_else(|e| e.into_inner());
                job.shutdown = true;
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
        let sum = AtomicUsize::new(0);
        Serial.run(5, &|i| {
            sum.fetch_add(i, Ordering::Relaxed);
        });
        assert_eq!(sum.load(Ordering::Relaxed), 10);
    }
}
