//! Splitting a step's loops into tasks with disjoint outputs.

use crate::error::{Error, Result};
use core::cell::UnsafeCell;
use core::marker::PhantomData;
use core::ops::Range;
use core::sync::atomic::{AtomicU8, Ordering};

/// Mutable access to disjoint parts of one slice from parallel tasks.
pub struct Disjoint<'a, T> {
    ptr: *mut T,
    len: usize,
    _m: PhantomData<&'a mut [T]>,
}

// SAFETY: `Disjoint` hands out `&mut` sub-slices only through the unsafe `range`, whose callers
// guarantee that concurrently used ranges never overlap; moving or sharing the pointer between
// threads is then as safe as sending the `&mut [T]` parts themselves, which needs `T: Send`.
unsafe impl<T: Send> Sync for Disjoint<'_, T> {}
// SAFETY: as above.
unsafe impl<T: Send> Send for Disjoint<'_, T> {}

impl<'a, T> Disjoint<'a, T> {
    /// Wraps `s` for the duration of its borrow.
    pub fn new(s: &'a mut [T]) -> Self {
        Disjoint { ptr: s.as_mut_ptr(), len: s.len(), _m: PhantomData }
    }

    /// The elements `r` (an empty slice if `r` is not inside the slice).
    ///
    /// # Safety
    /// No two ranges in use at the same time may overlap.
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn range(&self, r: Range<usize>) -> &'a mut [T] {
        if r.start > r.end || r.end > self.len {
            return &mut [];
        }
        // SAFETY: in bounds (checked above) of a slice borrowed mutably for 'a; the caller
        // guarantees no overlapping range is alive.
        unsafe { core::slice::from_raw_parts_mut(self.ptr.add(r.start), r.end - r.start) }
    }
}

/// A value that the tasks of one job build at most once, in place: whichever task needs it
/// first builds it, and any other task that needs it meanwhile waits for that build. A task only
/// ever waits on a build that a running task has started, so no order in which an executor runs
/// the tasks can deadlock. (A build must not panic: its waiters would spin forever.)
pub struct BuildOnce<'a, T> {
    ptr: *mut T,
    state: AtomicU8,
    /// The build's error, written by the builder before it publishes `FAILED`.
    error: UnsafeCell<Option<Error>>,
    _m: PhantomData<&'a mut T>,
}

const TODO: u8 = 0;
const BUILDING: u8 = 1;
const BUILT: u8 = 2;
const FAILED: u8 = 3;

// SAFETY: the value is written only by the one task that moved the state from `TODO` to
// `BUILDING`, and read (shared) only after `BUILT` was published with release ordering and seen
// with acquire ordering; the error likewise with `FAILED`. So sharing the cell between threads is
// as safe as sending the `&mut T` to the builder and then sharing `&T`, which needs `T: Send + Sync`.
unsafe impl<T: Send + Sync> Sync for BuildOnce<'_, T> {}

impl<'a, T> BuildOnce<'a, T> {
    /// Wraps `value` (not yet built) for the duration of its borrow.
    pub fn new(value: &'a mut T) -> Self {
        BuildOnce { ptr: value, state: AtomicU8::new(TODO), error: UnsafeCell::new(None), _m: PhantomData }
    }

    /// The value once built: builds it with `build` when no task has started to, otherwise waits
    /// for the task that has.
    ///
    /// # Errors
    /// The build's error, to every caller, whichever task ran it.
    pub fn get(&self, build: impl FnOnce(&mut T) -> Result<()>) -> Result<&T> {
        if self.state.compare_exchange(TODO, BUILDING, Ordering::Acquire, Ordering::Acquire).is_ok() {
            // SAFETY: this call alone moved the state out of `TODO`, so nothing else touches the
            // value or the error until the state below is published.
            let result = build(unsafe { &mut *self.ptr });
            if let Err(e) = result {
                // SAFETY: as above.
                unsafe { *self.error.get() = Some(e) };
                self.state.store(FAILED, Ordering::Release);
            } else {
                self.state.store(BUILT, Ordering::Release);
            }
        }
        loop {
            match self.state.load(Ordering::Acquire) {
                // SAFETY: built and published; from now on only shared references exist.
                BUILT => return Ok(unsafe { &*self.ptr }),
                FAILED => {
                    // SAFETY: written before `FAILED` was published, never written again.
                    let e = unsafe { (*self.error.get()).clone() };
                    return Err(e.unwrap_or(Error::Empty { what: "build" }));
                }
                _ => core::hint::spin_loop(),
            }
        }
    }
}

/// Task `t` of `n` over `total` items: a contiguous range, sizes differing by at most one.
pub fn split(total: usize, n: usize, t: usize) -> Range<usize> {
    (t * total / n)..((t + 1) * total / n)
}

/// Edge boundaries for `n` tasks over edges sorted by target, moved forward so that no target's
/// edges straddle two tasks (each task then owns its targets' sums).
pub fn target_bounds(target: &[u32], n: usize, out: &mut [usize]) {
    let e = target.len();
    out[0] = 0;
    for t in 1..n {
        let mut b = (t * e / n).max(out[t - 1]);
        while b > 0 && b < e && target[b] == target[b - 1] {
            b += 1;
        }
        out[t] = b;
    }
    out[n] = e;
}

/// The first error any task recorded.
pub fn first_error(errors: &mut [Option<Error>]) -> Result<()> {
    for e in errors.iter_mut() {
        if let Some(e) = e.take() {
            return Err(e);
        }
    }
    Ok(())
}
