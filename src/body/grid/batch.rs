//! Batched queries: a slice of queries with optional hints, tile by tile, serially or split
//! into chunks over an executor; and the argument checks the body's frame queries share.

use super::query::{consider, found};
use super::scan::{Best, Lanes};
use super::tile::{PortableTile, TileBest, TILE};
use super::{dist2, Nearest, PointGrid, NONE};
#[cfg(target_arch = "x86_64")]
use super::{scan::x86, tile};
use crate::error::{Error, Result};
use crate::exec::par::{split, Disjoint};
use crate::exec::Executor;
use crate::math::finite3;
use core::ops::Range;
use core::sync::atomic::{AtomicUsize, Ordering};

impl PointGrid {
    /// For every query point (metres), the nearest point within `radius`, see
    /// [`nearest_within_one`](Self::nearest_within_one). Allocates nothing.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `out` is not as long as `queries`; [`Error::OutOfRange`] for a
    /// negative or non-finite radius; [`Error::NonFinite`] for a NaN/Inf query coordinate (`out`
    /// is then partly written).
    pub fn nearest_within(&self, queries: &[[f32; 3]], radius: f32, out: &mut [Option<Nearest>]) -> Result<()> {
        self.nearest_within_hinted(queries, radius, &[], out)
    }

    /// As [`nearest_within`](Self::nearest_within) with one hint per query (see
    /// [`nearest_within_one_hinted`](Self::nearest_within_one_hinted)), or `hints` empty for none.
    ///
    /// # Errors
    /// As [`nearest_within`](Self::nearest_within); [`Error::SizeMismatch`] for hints neither
    /// empty nor one per query.
    pub fn nearest_within_hinted(
        &self,
        queries: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<()> {
        check_within(queries.len(), hints.len(), out.len(), radius)?;
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is only set when the CPU has AVX2 (checked in `new`).
            return unsafe { self.within_batch_avx2(queries, radius, hints, out) };
        }
        self.within_batch::<Lanes, PortableTile>(queries, radius, hints, out)
    }

    /// The batch loop compiled with AVX2, so that the whole search inlines around the scans.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn within_batch_avx2(
        &self,
        queries: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<()> {
        self.within_batch::<x86::Avx2Best, tile::x86::Avx2Tile>(queries, radius, hints, out)
    }

    /// The radius queries tile by tile: each query's start is the single search's (the limit,
    /// or the hint where it is within it); a tile not worth searching as one box is searched
    /// query by query.
    #[inline(always)]
    fn within_batch<B: Best, T: TileBest>(
        &self,
        queries: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<()> {
        let r2 = radius * radius;
        for (t, (qs, os)) in queries.chunks(TILE).zip(out.chunks_mut(TILE)).enumerate() {
            let first = t * TILE;
            if let Some(k) = qs.iter().position(|q| !finite3(*q)) {
                return Err(Error::NonFinite { what: "query point", index: first + k });
            }
            let hint = |k: usize| hints.get(first + k).copied().unwrap_or(NONE);
            let mut start = [(NONE, r2); TILE];
            for (k, (q, s)) in qs.iter().zip(start.iter_mut()).enumerate() {
                if let Some(p) = self.point(hint(k)) {
                    consider(s, dist2(p, *q), hint(k));
                }
            }
            let mut answers = [(NONE, 0.0); TILE];
            if self.search_tile::<T>(qs, &start[..qs.len()], &mut answers[..qs.len()]) {
                for (o, f) in os.iter_mut().zip(answers) {
                    *o = found(f);
                }
            } else {
                for (k, (q, o)) in qs.iter().zip(os.iter_mut()).enumerate() {
                    *o = self.within_one::<B>(*q, radius, hint(k));
                }
            }
        }
        Ok(())
    }

    /// For every query point (metres), the nearest point with no distance limit, see
    /// [`nearest_one`](Self::nearest_one). Allocates nothing.
    ///
    /// # Errors
    /// [`Error::Empty`] when the grid holds no point; [`Error::SizeMismatch`] when `out` is not as
    /// long as `queries`; [`Error::NonFinite`] for a NaN/Inf query coordinate (`out` is then
    /// partly written).
    pub fn nearest(&self, queries: &[[f32; 3]], out: &mut [Nearest]) -> Result<()> {
        self.nearest_hinted(queries, &[], out)
    }

    /// As [`nearest`](Self::nearest) with one hint per query (see
    /// [`nearest_one_hinted`](Self::nearest_one_hinted)), or `hints` empty for none. Last
    /// frame's answers make good hints.
    ///
    /// # Errors
    /// As [`nearest`](Self::nearest); [`Error::SizeMismatch`] for hints neither empty nor one per
    /// query.
    pub fn nearest_hinted(&self, queries: &[[f32; 3]], hints: &[u32], out: &mut [Nearest]) -> Result<()> {
        check_batch(queries.len(), hints.len(), out.len())?;
        if self.n_points == 0 {
            return Err(Error::Empty { what: "point grid" });
        }
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is only set when the CPU has AVX2 (checked in `new`).
            return unsafe { self.nearest_batch_avx2(queries, hints, out) };
        }
        self.nearest_batch::<Lanes, PortableTile>(queries, hints, out)
    }

    /// The batch loop compiled with AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn nearest_batch_avx2(&self, queries: &[[f32; 3]], hints: &[u32], out: &mut [Nearest]) -> Result<()> {
        self.nearest_batch::<x86::Avx2Best, tile::x86::Avx2Tile>(queries, hints, out)
    }

    /// The unbounded queries tile by tile where every query of the tile has a hint (its
    /// distance bounds the search); otherwise, or when the tile is not worth searching as one
    /// box, query by query.
    #[inline(always)]
    fn nearest_batch<B: Best, T: TileBest>(
        &self,
        queries: &[[f32; 3]],
        hints: &[u32],
        out: &mut [Nearest],
    ) -> Result<()> {
        // Non-empty grid and finite query: a search always returns a point.
        let missing = Nearest { index: 0, distance: f32::INFINITY };
        for (t, (qs, os)) in queries.chunks(TILE).zip(out.chunks_mut(TILE)).enumerate() {
            let first = t * TILE;
            if let Some(k) = qs.iter().position(|q| !finite3(*q)) {
                return Err(Error::NonFinite { what: "query point", index: first + k });
            }
            let hint = |k: usize| hints.get(first + k).copied().unwrap_or(NONE);
            let mut start = [(NONE, f32::INFINITY); TILE];
            let mut bounded = true;
            for (k, (q, s)) in qs.iter().zip(start.iter_mut()).enumerate() {
                match self.point(hint(k)).map(|p| dist2(p, *q)) {
                    Some(d2) if d2.is_finite() => *s = (hint(k), d2),
                    _ => bounded = false,
                }
            }
            let mut answers = [(NONE, 0.0); TILE];
            if bounded && self.search_tile::<T>(qs, &start[..qs.len()], &mut answers[..qs.len()]) {
                for (o, f) in os.iter_mut().zip(answers) {
                    *o = found(f).unwrap_or(missing);
                }
            } else {
                for (k, (q, o)) in qs.iter().zip(os.iter_mut()).enumerate() {
                    *o = self.nearest_one_with::<B>(*q, hint(k)).unwrap_or(missing);
                }
            }
        }
        Ok(())
    }

    /// As [`nearest_within_hinted`](Self::nearest_within_hinted), with the queries split into
    /// contiguous chunks run as tasks of `exec` (all its threads search the same grid). Same
    /// results as the serial call for any executor. Allocates nothing.
    ///
    /// # Errors
    /// As [`nearest_within_hinted`](Self::nearest_within_hinted); every query is checked before
    /// any is searched, so on error `out` is untouched.
    pub fn nearest_within_on(
        &self,
        exec: &dyn Executor,
        queries: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<()> {
        check_within(queries.len(), hints.len(), out.len(), radius)?;
        check_queries(queries)?;
        in_chunks(exec, queries.len(), out, |r, o| {
            self.nearest_within_hinted(&queries[r.clone()], radius, hint_range(hints, r), o)
        })
    }

    /// As [`nearest_hinted`](Self::nearest_hinted), with the queries split into contiguous
    /// chunks run as tasks of `exec`. Same results as the serial call for any executor.
    /// Allocates nothing.
    ///
    /// # Errors
    /// As [`nearest_hinted`](Self::nearest_hinted); every query is checked before any is
    /// searched, so on error `out` is untouched.
    pub fn nearest_on(
        &self,
        exec: &dyn Executor,
        queries: &[[f32; 3]],
        hints: &[u32],
        out: &mut [Nearest],
    ) -> Result<()> {
        check_batch(queries.len(), hints.len(), out.len())?;
        if self.n_points == 0 {
            return Err(Error::Empty { what: "point grid" });
        }
        check_queries(queries)?;
        in_chunks(exec, queries.len(), out, |r, o| self.nearest_hinted(&queries[r.clone()], hint_range(hints, r), o))
    }
}

pub(in crate::body) fn check_batch(queries: usize, hints: usize, out: usize) -> Result<()> {
    if out != queries {
        return Err(Error::SizeMismatch { what: "query output", expected: queries, got: out });
    }
    if hints != 0 && hints != queries {
        return Err(Error::SizeMismatch { what: "query hints", expected: queries, got: hints });
    }
    Ok(())
}

/// [`check_batch`] and a finite, non-negative radius.
pub(in crate::body) fn check_within(queries: usize, hints: usize, out: usize, radius: f32) -> Result<()> {
    check_batch(queries, hints, out)?;
    if !(radius >= 0.0 && radius.is_finite()) {
        return Err(Error::OutOfRange { what: "query radius", index: 0 });
    }
    Ok(())
}

/// The first query with a NaN/Inf coordinate, as an error.
pub(in crate::body) fn check_queries(queries: &[[f32; 3]]) -> Result<()> {
    match queries.iter().position(|q| !finite3(*q)) {
        Some(i) => Err(Error::NonFinite { what: "query point", index: i }),
        None => Ok(()),
    }
}

/// The hints of the queries `r` (empty when there are none).
pub(in crate::body) fn hint_range(hints: &[u32], r: Range<usize>) -> &[u32] {
    hints.get(r).unwrap_or(&[])
}

/// Queries per task below which splitting costs more than it saves (a search takes 0.1-0.5 µs,
/// handing out a task about 1 µs).
const MIN_CHUNK: usize = 256;

/// How many chunks `n` queries are split into on `threads` threads: eight per thread, since
/// queries differ in cost (on the body-query bench at 2 threads, eight rather than four per thread
/// took the runtime's query from 0.52 to 0.44 ms and the whole query in one job from 1.14 to
/// 1.06 ms; sixteen gained nothing), but none below [`MIN_CHUNK`] queries (1 on one thread).
pub(in crate::body) fn chunks_for(threads: usize, n: usize) -> usize {
    if threads <= 1 {
        1
    } else {
        (8 * threads).min(n / MIN_CHUNK).max(1)
    }
}

/// Runs `f(range, out[range])` over contiguous chunks of `0..n` as tasks of `exec`: a few
/// chunks per thread, since queries differ in cost. Returns the first error of a chunk.
fn in_chunks<T: Send>(
    exec: &dyn Executor,
    n: usize,
    out: &mut [T],
    f: impl Fn(Range<usize>, &mut [T]) -> Result<()> + Sync,
) -> Result<()> {
    let tasks = chunks_for(exec.parallelism(), n);
    if tasks == 1 {
        return f(0..n, out);
    }
    let out = Disjoint::new(out);
    // The lowest failing chunk, `usize::MAX` for none (the callers validate their input first,
    // so this only guards against a broken invariant).
    let failed = AtomicUsize::new(usize::MAX);
    exec.run(tasks, &|t| {
        let r = split(n, tasks, t);
        // SAFETY: the chunks of `split` are disjoint.
        let o = unsafe { out.range(r.clone()) };
        if f(r, o).is_err() {
            failed.fetch_min(t, Ordering::Relaxed);
        }
    });
    match failed.load(Ordering::Relaxed) {
        usize::MAX => Ok(()),
        t => {
            let r = split(n, tasks, t);
            // Rerun the failing chunk on its own to return its error.
            // SAFETY: no task is running any more.
            f(r.clone(), unsafe { out.range(r) })
        }
    }
}
