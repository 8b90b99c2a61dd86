//! Splitting a step's loops into tasks with disjoint outputs.

use crate::error::{Error, Result};
use core::marker::PhantomData;
use core::ops::Range;

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
