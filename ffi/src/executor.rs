//! An engine's job system as the sim's [`Executor`]: `hood_executor` and the adapter that runs
//! the step's tasks through it.

use crate::consts::HOOD_LOG_ERROR;
use crate::extensible::{read_struct, Extensible};
use crate::guard::{guard, panic_message};
use crate::log;
use crate::sim::{hood_sim, sim_mut};
use crate::status::{hood_status, Failure};
use hood::sim::{Executor, Serial, ThreadPool};
use std::ffi::c_void;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};

/// One task of a step (`extern "C"` is cdecl on 32-bit Windows, as `HOOD_CALL` declares it).
pub type hood_task_fn = Option<unsafe extern "C" fn(ctx: *mut c_void, index: u32)>;

/// An engine's job system (see the header for the contract of `run`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct hood_executor {
    /// `sizeof(hood_executor)` in the caller's header (see its Conventions).
    pub struct_size: u32,
    /// Passed back to `run`.
    pub user: *mut c_void,
    /// Tasks worth splitting into (0 counts as 1).
    pub parallelism: u32,
    /// Runs `task(ctx, i)` for every `i < n_tasks`. `C-unwind`: an exception thrown out of it,
    /// against the header's contract, unwinds to the export's boundary and aborts the process
    /// there (through an `extern "C"` type it would be undefined behaviour).
    pub run: Option<unsafe extern "C-unwind" fn(user: *mut c_void, n_tasks: u32, task: hood_task_fn, ctx: *mut c_void)>,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers, a raw pointer and an optional
// function pointer (any bits are a valid `Option<fn>`; calling it is the caller's contract).
unsafe impl Extensible for hood_executor {
    const NAME: &'static str = "hood_executor";
}

/// Adapts a C job system to [`Executor`].
struct CExecutor {
    raw: hood_executor,
    run: unsafe extern "C-unwind" fn(*mut c_void, u32, hood_task_fn, *mut c_void),
}

// SAFETY: the header makes `user` and `run` usable from the thread that steps the sim (the
// caller's promise); the library itself calls `run` only from that thread.
unsafe impl Send for CExecutor {}
// SAFETY: as above; `CExecutor` has no interior mutability of its own.
unsafe impl Sync for CExecutor {}

/// Task indices a C executor may be handed at once: each has a claim bit, so that an index run
/// twice is refused instead of aliasing a task's buffers (larger jobs run serially).
const C_EXECUTOR_MAX_TASKS: usize = 4096;

struct TaskCtx<'a> {
    task: &'a (dyn Fn(usize) + Sync),
    n: usize,
    calls: AtomicUsize,
    /// One bit per task index, set by the first call of that index.
    claimed: [AtomicU64; C_EXECUTOR_MAX_TASKS / 64],
    bad: AtomicBool,
    panicked: AtomicBool,
}

unsafe extern "C" fn run_task(ctx: *mut c_void, index: u32) {
    if ctx.is_null() {
        return;
    }
    // SAFETY: `ctx` is the `TaskCtx` that `CExecutor::run` passed to `run`, alive until `run`
    // returns (the executor contract: all tasks finish before `run` returns).
    let c = unsafe { &*(ctx as *const TaskCtx<'_>) };
    let i = index as usize;
    if i >= c.n {
        c.bad.store(true, Ordering::SeqCst);
        return;
    }
    // An index run a second time would alias the first run's buffers: refuse it.
    let bit = 1u64 << (i % 64);
    if c.claimed[i / 64].fetch_or(bit, Ordering::AcqRel) & bit != 0 {
        c.bad.store(true, Ordering::SeqCst);
        return;
    }
    c.calls.fetch_add(1, Ordering::SeqCst);
    let _inside = log::Inside::enter();
    // No unwinding through the C job system: remember the panic and re-raise it after `run`.
    if let Err(payload) = catch_unwind(AssertUnwindSafe(|| (c.task)(i))) {
        let _ = catch_unwind(AssertUnwindSafe(|| {
            log::log(HOOD_LOG_ERROR, &format!("a step task panicked: {}", panic_message(&*payload)))
        }));
        c.panicked.store(true, Ordering::SeqCst);
    }
}

// SAFETY: whatever the C `run` does, `run_task` runs each index in `0..n` at most once (claim
// bits) and `run` returns only after the C `run` has (the header's contract: every task has
// finished by then); a missing or repeated index is reported as a failed step.
unsafe impl Executor for CExecutor {
    fn parallelism(&self) -> usize {
        self.raw.parallelism.max(1) as usize
    }

    fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
        if n == 0 {
            return;
        }
        if n > C_EXECUTOR_MAX_TASKS {
            (0..n).for_each(task);
            return;
        }
        let n32 = n as u32;
        let ctx = TaskCtx {
            task,
            n,
            calls: AtomicUsize::new(0),
            claimed: std::array::from_fn(|_| AtomicU64::new(0)),
            bad: AtomicBool::new(false),
            panicked: AtomicBool::new(false),
        };
        // SAFETY: a C function supplied through `hood_sim_set_executor`, called as documented;
        // `ctx` outlives the call.
        unsafe { (self.run)(self.raw.user, n32, Some(run_task), &ctx as *const TaskCtx<'_> as *mut c_void) };
        // Panics here are caught by `guard` at the export.
        assert!(!ctx.panicked.load(Ordering::SeqCst), "a step task panicked");
        let calls = ctx.calls.load(Ordering::SeqCst);
        assert!(
            !ctx.bad.load(Ordering::SeqCst) && calls == n,
            "the executor did not run every task exactly once ({calls} calls for {n} tasks)"
        );
    }
}

/// Plugs in (or with NULL removes) an engine executor.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `executor` is NULL or holds the `struct_size` bytes it
/// states and keeps the contract in the header.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_set_executor(sim: *mut hood_sim, executor: *const hood_executor) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        let exec: Box<dyn Executor> = if executor.is_null() {
            let threads = s.sim.config().threads;
            if threads > 1 {
                Box::new(ThreadPool::new(threads))
            } else {
                Box::new(Serial)
            }
        } else {
            // SAFETY: non-null; `struct_size` readable bytes (caller).
            let raw = unsafe { read_struct(executor, "executor")? };
            let run = raw.run.ok_or(Failure::Null("executor run"))?;
            Box::new(CExecutor { raw, run })
        };
        s.sim.set_executor(exec);
        Ok(())
    })
}
