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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exec::Executor;
    use alloc::vec;
    use alloc::vec::Vec;
    use core::sync::atomic::AtomicUsize;

    /// The executors the primitives run under: serial, and a pool when `std` is on.
    fn executors() -> Vec<alloc::boxed::Box<dyn Executor>> {
        #[allow(unused_mut)]
        let mut e: Vec<alloc::boxed::Box<dyn Executor>> = vec![alloc::boxed::Box::new(crate::exec::Serial)];
        #[cfg(feature = "std")]
        e.push(alloc::boxed::Box::new(crate::exec::ThreadPool::new(3)));
        e
    }

    #[test]
    fn exec_disjoint_ranges_are_written_from_parallel_tasks() {
        for exec in executors() {
            for (total, n) in [(0usize, 3usize), (1, 4), (10, 3), (37, 5)] {
                let mut out = vec![usize::MAX; total];
                let parts = Disjoint::new(&mut out);
                exec.run(n, &|t| {
                    // SAFETY: `split` gives the tasks disjoint ranges.
                    let mine = unsafe { parts.range(split(total, n, t)) };
                    for (k, x) in mine.iter_mut().enumerate() {
                        *x = split(total, n, t).start + k;
                    }
                });
                assert_eq!(out, (0..total).collect::<Vec<_>>());
            }
        }
        // Outside the slice, or reversed: empty, never out of bounds.
        let mut v = [1u8, 2, 3];
        let d = Disjoint::new(&mut v);
        // SAFETY: one range in use at a time.
        unsafe {
            assert!(d.range(2..5).is_empty());
            assert!(d.range(4..4).is_empty());
            #[allow(clippy::reversed_empty_ranges)]
            let reversed = d.range(2..1);
            assert!(reversed.is_empty());
            assert_eq!(d.range(1..3), &[2, 3]);
        }
    }

    #[test]
    fn exec_build_once_builds_once_and_shares_the_value_or_error() {
        for exec in executors() {
            let builds = AtomicUsize::new(0);
            let mut value = Vec::new();
            let once = BuildOnce::new(&mut value);
            let seen = AtomicUsize::new(0);
            exec.run(8, &|_| {
                let v = once
                    .get(|v| {
                        builds.fetch_add(1, Ordering::Relaxed);
                        v.extend_from_slice(&[1u32, 2, 3]);
                        Ok(())
                    })
                    .unwrap();
                seen.fetch_add(v.iter().sum::<u32>() as usize, Ordering::Relaxed);
            });
            assert_eq!(builds.load(Ordering::Relaxed), 1);
            assert_eq!(seen.load(Ordering::Relaxed), 8 * 6);

            let mut failing = 0u32;
            let once = BuildOnce::new(&mut failing);
            let errors = AtomicUsize::new(0);
            exec.run(5, &|_| {
                let r = once.get(|_| Err(Error::Empty { what: "test build" }));
                if matches!(r, Err(Error::Empty { what: "test build" })) {
                    errors.fetch_add(1, Ordering::Relaxed);
                }
            });
            assert_eq!(errors.load(Ordering::Relaxed), 5);
        }
    }

    #[test]
    fn exec_target_bounds_never_split_a_target() {
        let target = [0u32, 0, 0, 1, 2, 2, 2, 2, 3, 5, 5];
        for n in 1..=6 {
            let mut b = vec![0usize; n + 1];
            target_bounds(&target, n, &mut b);
            assert_eq!((b[0], b[n]), (0, target.len()));
            for t in 1..n {
                assert!(b[t - 1] <= b[t], "{b:?}");
                assert!(b[t] == 0 || b[t] == target.len() || target[b[t]] != target[b[t] - 1], "{b:?}");
            }
        }
        let mut errors = [None, Some(Error::Empty { what: "a" }), Some(Error::Empty { what: "b" })];
        assert!(matches!(first_error(&mut errors), Err(Error::Empty { what: "a" })));
    }
}
