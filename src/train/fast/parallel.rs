//! Running the fast path's loops in parallel: the fixed [`PARTS`] split, the reduction of the
//! parts' partial gradients in part order, and the row-split gathers, scatters and sums (each
//! part writes its own rows through the execution layer's [`Disjoint`]).

use super::{Ctx, PartBufs, PARTS};
use crate::exec::par::{self, Disjoint};
use core::ops::Range;

/// Part `p` of [`PARTS`] over `total` rows.
fn split(total: usize, p: usize) -> Range<usize> {
    par::split(total, PARTS, p)
}

impl Ctx<'_> {
    /// Adds the partial gradients over `span` of the parts that ran on `rows` rows into the
    /// gradient, in part order (the same sum whatever the thread count).
    pub(super) fn reduce(&self, parts: &[PartBufs], rows: usize, span: Range<usize>) {
        let Some(gs) = self.grad else { return };
        self.parts(span.len(), &|_, r| {
            // SAFETY: disjoint ranges of the gradient.
            let g = unsafe { gs.range(span.start + r.start..span.start + r.end) };
            // Parts with no rows did not run: their scratch holds an earlier product's share.
            for (_, pb) in parts.iter().enumerate().filter(|&(p, _)| !split(rows, p).is_empty()) {
                g.iter_mut().zip(&pb.grad[r.clone()]).for_each(|(a, b)| *a += *b);
            }
        });
    }

    /// Calls `f(p, range)` for every non-empty range `p` of `0..rows`.
    pub(super) fn parts(&self, rows: usize, f: &(dyn Fn(usize, Range<usize>) + Sync)) {
        if rows == 0 {
            return;
        }
        self.exec.run(PARTS, &|p| {
            let r = split(rows, p);
            if !r.is_empty() {
                f(p, r);
            }
        });
    }

    /// `dst[idx[e]] += src[e]` (rows `w` wide). Each part owns a range of destination rows and
    /// scans every index, so repeated indices sum in edge order whatever the split (rows of
    /// whole vectors: splitting by columns left a few floats per row and part at small widths).
    pub(super) fn scatter_add(&self, src: &[f32], idx: &[u32], w: usize, dst: &mut [f32]) {
        if w == 0 {
            return;
        }
        let rows = dst.len() / w;
        let ds = Disjoint::new(dst);
        self.exec.run(PARTS, &|p| {
            let own = split(rows, p);
            if own.is_empty() {
                return;
            }
            // SAFETY: destination row ranges of different parts are disjoint.
            let d = unsafe { ds.range(own.start * w..own.end * w) };
            for (row, &i) in src.chunks_exact(w).zip(idx) {
                let i = i as usize;
                if own.contains(&i) {
                    let o = (i - own.start) * w;
                    d[o..o + w].iter_mut().zip(row).for_each(|(a, b)| *a += *b);
                }
            }
        });
    }

    /// `dst[e] = src[idx[e]]` (+ `add[e]` when given), row-split.
    pub(super) fn gather(&self, src: &[f32], idx: &[u32], w: usize, add: Option<&[f32]>, dst: &mut [f32]) {
        let ds = Disjoint::new(dst);
        self.parts(idx.len(), &|_, r| {
            // SAFETY: row ranges of different parts are disjoint.
            let d = unsafe { ds.range(r.start * w..r.end * w) };
            for (e, row) in r.zip(d.chunks_exact_mut(w)) {
                let i = idx[e] as usize;
                row.copy_from_slice(&src[i * w..(i + 1) * w]);
                if let Some(add) = add {
                    row.iter_mut().zip(&add[e * w..(e + 1) * w]).for_each(|(a, b)| *a += *b);
                }
            }
        });
    }

    /// `dst = a + b`, row-split.
    pub(super) fn sum(&self, a: &[f32], b: &[f32], dst: &mut [f32]) {
        let ds = Disjoint::new(dst);
        self.parts(a.len(), &|_, r| {
            // SAFETY: disjoint ranges.
            let d = unsafe { ds.range(r.clone()) };
            d.iter_mut().zip(&a[r.clone()]).zip(&b[r]).for_each(|((o, x), y)| *o = *x + *y);
        });
    }
}
