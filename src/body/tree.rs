//! A bounding-box tree over a moving point set (body vertices or face centroids), refitted every
//! frame without allocation, answering exact nearest-point queries.
//!
//! Why a tree and not a uniform grid: body meshes are far from uniform (hands, face and feet hold
//! hundreds of vertices within the 3 cm body-edge radius, the trunk a few dozen), and a tree's
//! leaves adapt to the density where a grid's cells cannot.
//!
//! Layout: an implicit complete binary tree (node `i` has children `2i + 1`, `2i + 2`) over a
//! permutation of the points, built by median splits along the widest axis until leaves hold at
//! most [`LEAF`] points. The permutation is built once and kept while the points move (a body
//! moves mostly rigidly per limb, so neighbours stay neighbours): every
//! [`rebuild`](PointTree::rebuild) gathers the coordinates in leaf order and refits the boxes
//! bottom-up, and rebuilds the permutation only when the leaves' boxes have grown to
//! [`REBUILD_GROWTH`] times their size after the last build, or the point count changed.
//!
//! Exactness: boxes are the tight bounds of their points at the current frame, and a box's
//! distance `max(lo - q, q - hi, 0)` per axis, squared and summed in the same order as a point's
//! (`(dx² + dy²) + dz²` in `f32`), never exceeds the distance of any point inside it (rounding is
//! monotonic), so pruning boxes strictly farther than the best point never drops a point that
//! could win or tie. Ties: lowest point index, as [`super::PointGrid`].

use super::grid::Nearest;
use crate::error::{Error, Result};
use crate::math::finite3;
use alloc::vec;
use alloc::vec::Vec;
use glam::Vec4;

/// Most points per leaf.
pub const LEAF: usize = 8;
/// The permutation is rebuilt when the leaves' summed box extents exceed this factor times
/// their value after the last build (speed only: results are exact with any permutation).
pub const REBUILD_GROWTH: f32 = 1.5;
const NONE: u32 = u32::MAX;
/// Enough for any depth reachable with `u32` point counts (one pending node per level).
const STACK: usize = 32;

/// A tree over at most `capacity` points (fixed at creation). [`rebuild`](Self::rebuild) refits
/// it to the points of the frame; the queries write into caller slices. Neither allocates.
#[derive(Clone, Debug)]
pub struct PointTree {
    capacity: usize,
    n_points: usize,
    /// Point count the permutation was built for (0: none yet).
    built_n: usize,
    depth: u32,
    /// `perm[leaf_start[j]..leaf_start[j + 1]]` are the points of leaf `j`.
    leaf_start: Vec<u32>,
    /// Sorted position -> input index.
    perm: Vec<u32>,
    /// Input index -> sorted position.
    rank: Vec<u32>,
    /// Coordinates in sorted order, one array per axis (leaves scan four points at once).
    sorted: [Vec<f32>; 3],
    /// Split axis of every internal node (heap order).
    node_axis: Vec<u8>,
    /// Leaf of every sorted position.
    leaf_of: Vec<u32>,
    /// Node boxes in heap order.
    node_lo: Vec<[f32; 3]>,
    node_hi: Vec<[f32; 3]>,
    /// Summed leaf box extents right after the last build.
    built_spread: f32,
    builds: u64,
}

/// Tree depth for `n` points: the smallest with at most [`LEAF`] points per leaf.
fn depth_for(n: usize) -> u32 {
    let mut d = 0;
    while n.div_ceil(1 << d) > LEAF {
        d += 1;
    }
    d
}

impl PointTree {
    /// A tree for up to `capacity` points (memory: about `40·capacity` bytes).
    ///
    /// # Errors
    /// [`Error::OutOfRange`] when `capacity` does not fit in `u32`.
    pub fn new(capacity: usize) -> Result<PointTree> {
        if capacity >= u32::MAX as usize {
            return Err(Error::OutOfRange { what: "tree capacity", index: capacity });
        }
        let d = depth_for(capacity);
        let leaves = 1usize << d;
        Ok(PointTree {
            capacity,
            n_points: 0,
            built_n: 0,
            depth: 0,
            leaf_start: vec![0; leaves + 1],
            perm: vec![0; capacity],
            rank: vec![0; capacity],
            sorted: [vec![0.0; capacity], vec![0.0; capacity], vec![0.0; capacity]],
            node_axis: vec![0; leaves],
            leaf_of: vec![0; capacity],
            node_lo: vec![[0.0; 3]; 2 * leaves - 1],
            node_hi: vec![[0.0; 3]; 2 * leaves - 1],
            built_spread: 0.0,
            builds: 0,
        })
    }

    /// Maximum number of points.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
    /// Number of points of the last rebuild.
    pub fn len(&self) -> usize {
        self.n_points
    }
    /// True when the last rebuild had no point.
    pub fn is_empty(&self) -> bool {
        self.n_points == 0
    }
    /// Leaves of the current tree.
    pub fn leaves(&self) -> usize {
        1 << self.depth
    }
    /// How many times the permutation has been built (the other rebuilds only refitted).
    pub fn builds(&self) -> u64 {
        self.builds
    }
    /// Tight bounds `(min, max)` of the points of the last rebuild (metres).
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        if self.n_points == 0 {
            return ([0.0; 3], [0.0; 3]);
        }
        (self.node_lo[0], self.node_hi[0])
    }

    /// Refits the tree to `points` (the frame's positions, metres; the same points in the same
    /// order as before, moved, or any new set), rebuilding its permutation when needed (see the
    /// module notes). Allocates nothing.
    ///
    /// # Errors
    /// [`Error::CapacityExceeded`] for more than `capacity` points; [`Error::NonFinite`] for a
    /// NaN/Inf coordinate. The tree is left empty on error.
    pub fn rebuild(&mut self, points: &[[f32; 3]]) -> Result<()> {
        self.n_points = 0;
        let n = points.len();
        if n > self.capacity {
            return Err(Error::CapacityExceeded { what: "tree points", capacity: self.capacity, needed: n });
        }
        if let Some(i) = points.iter().position(|p| !finite3(*p)) {
            return Err(Error::NonFinite { what: "tree point", index: i });
        }
        if n == 0 {
            return Ok(());
        }
        if n != self.built_n {
            self.build(points);
        } else {
            let spread = self.refit(points);
            if spread > REBUILD_GROWTH * self.built_spread {
                self.build(points);
            }
        }
        self.n_points = n;
        Ok(())
    }

    /// Builds the permutation by median splits, then refits.
    fn build(&mut self, points: &[[f32; 3]]) {
        let n = points.len();
        self.depth = depth_for(n);
        for (i, p) in self.perm[..n].iter_mut().enumerate() {
            *p = i as u32;
        }
        self.split(points, 0, 0, n, 0);
        self.leaf_start[1 << self.depth] = n as u32;
        for j in 0..1usize << self.depth {
            let (a, b) = (self.leaf_start[j] as usize, self.leaf_start[j + 1] as usize);
            self.leaf_of[a..b].fill(j as u32);
        }
        for (at, &i) in self.perm[..n].iter().enumerate() {
            self.rank[i as usize] = at as u32;
        }
        self.built_n = n;
        self.built_spread = self.refit(points);
        self.builds += 1;
    }

    /// Orders `perm[a..b]` (the points of `node`, at `level`) into its subtree's leaves.
    fn split(&mut self, points: &[[f32; 3]], node: usize, a: usize, b: usize, level: u32) {
        if level == self.depth {
            self.leaf_start[node + 1 - (1 << self.depth)] = a as u32;
            return;
        }
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for &i in &self.perm[a..b] {
            let p = points[i as usize];
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        let axis = if ext[0] >= ext[1] && ext[0] >= ext[2] {
            0
        } else if ext[1] >= ext[2] {
            1
        } else {
            2
        };
        self.node_axis[node] = axis as u8;
        let mid = a + (b - a) / 2;
        // Ties broken by index so that the build is deterministic.
        self.perm[a..b].select_nth_unstable_by(mid - a, |&i, &j| {
            points[i as usize][axis].total_cmp(&points[j as usize][axis]).then(i.cmp(&j))
        });
        self.split(points, 2 * node + 1, a, mid, level + 1);
        self.split(points, 2 * node + 2, mid, b, level + 1);
    }

    /// Gathers the coordinates in sorted order and recomputes every box; returns the summed leaf
    /// box extents.
    fn refit(&mut self, points: &[[f32; 3]]) -> f32 {
        let n = points.len();
        let [xs, ys, zs] = &mut self.sorted;
        for (((&i, x), y), z) in self.perm[..n].iter().zip(&mut xs[..n]).zip(&mut ys[..n]).zip(&mut zs[..n]) {
            let p = points[i as usize];
            (*x, *y, *z) = (p[0], p[1], p[2]);
        }
        let leaves = 1usize << self.depth;
        let first = leaves - 1;
        let mut spread = 0.0f32;
        for j in 0..leaves {
            let (a, b) = (self.leaf_start[j] as usize, self.leaf_start[j + 1] as usize);
            let mut lo = [f32::INFINITY; 3];
            let mut hi = [f32::NEG_INFINITY; 3];
            for (k, axis) in self.sorted.iter().enumerate() {
                for &c in &axis[a..b] {
                    lo[k] = fmin(lo[k], c);
                    hi[k] = fmax(hi[k], c);
                }
            }
            spread += (hi[0] - lo[0]) + (hi[1] - lo[1]) + (hi[2] - lo[2]);
            self.node_lo[first + j] = lo;
            self.node_hi[first + j] = hi;
        }
        for i in (0..first).rev() {
            let (l, r) = (2 * i + 1, 2 * i + 2);
            self.node_lo[i] = [0, 1, 2].map(|k| fmin(self.node_lo[l][k], self.node_lo[r][k]));
            self.node_hi[i] = [0, 1, 2].map(|k| fmax(self.node_hi[l][k], self.node_hi[r][k]));
        }
        spread
    }

    /// The position of input point `i` of the last rebuild, if there is one.
    #[inline(always)]
    fn point(&self, i: u32) -> Option<[f32; 3]> {
        let at = *self.rank[..self.n_points].get(i as usize)? as usize;
        Some([self.sorted[0][at], self.sorted[1][at], self.sorted[2][at]])
    }

    /// The nearest point within `radius` (metres) of `q`, distance `<= radius` inclusive (in
    /// squared `f32` distances), lowest index on ties; `None` when no point is that close (or
    /// `q` has a NaN coordinate).
    pub fn nearest_within_one(&self, q: [f32; 3], radius: f32) -> Option<Nearest> {
        self.nearest_within_one_hinted(q, radius, NONE)
    }

    /// As [`nearest_within_one`](Self::nearest_within_one), starting from a guess: the point
    /// `hint` (any index `>= len()` means none). Same result whatever the hint.
    pub fn nearest_within_one_hinted(&self, q: [f32; 3], radius: f32, hint: u32) -> Option<Nearest> {
        if self.n_points == 0 || radius.is_nan() || radius < 0.0 {
            return None;
        }
        if q.iter().any(|c| c.is_nan()) {
            return None;
        }
        let mut best = (NONE, radius * radius);
        let leaf = match self.point(hint) {
            Some(p) => {
                consider(&mut best, dist2(p, q), hint);
                self.leaf_of[self.rank[hint as usize] as usize] as usize
            }
            None => self.leaf_at(q),
        };
        if box_dist2(q, self.node_lo[0], self.node_hi[0]) <= best.1 {
            self.search_from(q, leaf, &mut best);
        }
        found(best)
    }

    /// The nearest point to `q`, lowest index on ties, with no distance limit; `None` only when
    /// the tree is empty or `q` has a NaN coordinate. Coordinates beyond about 1e18 m overflow
    /// `f32` squared distances; such queries get a valid point index but not necessarily the
    /// nearest.
    pub fn nearest_one(&self, q: [f32; 3]) -> Option<Nearest> {
        self.nearest_one_hinted(q, NONE)
    }

    /// As [`nearest_one`](Self::nearest_one), starting from a guess: the point `hint` (e.g. last
    /// frame's answer; any index `>= len()` means none). Same result whatever the hint; a good
    /// one prunes most of the tree from the start.
    pub fn nearest_one_hinted(&self, q: [f32; 3], hint: u32) -> Option<Nearest> {
        if self.n_points == 0 || q.iter().any(|c| c.is_nan()) {
            return None;
        }
        let mut best = (NONE, f32::INFINITY);
        let leaf = match self.point(hint) {
            Some(p) => {
                consider(&mut best, dist2(p, q), hint);
                self.leaf_of[self.rank[hint as usize] as usize] as usize
            }
            None => self.leaf_at(q),
        };
        self.search_from(q, leaf, &mut best);
        if best.0 == NONE {
            // Only with overflowing distances: every box and point compared as infinite.
            best.0 = self.perm[0];
        }
        found(best)
    }

    /// The leaf whose split cells hold `q` (a descent by the split planes, no box tests).
    #[inline(always)]
    fn leaf_at(&self, q: [f32; 3]) -> usize {
        let first_leaf = (1usize << self.depth) - 1;
        let mut node = 0;
        while node < first_leaf {
            let (l, r) = (2 * node + 1, 2 * node + 2);
            let a = self.node_axis[node] as usize;
            node = if q[a] + q[a] < self.node_hi[l][a] + self.node_lo[r][a] { l } else { r };
        }
        node - first_leaf
    }

    /// Improves `best` with every point not strictly farther than it: scans leaf `leaf` first,
    /// then climbs to the root, searching each sibling subtree whose box is in reach. Every
    /// subtree off the path is a sibling of a node on it, so every point is considered or
    /// pruned by a box.
    #[inline]
    fn search_from(&self, q: [f32; 3], leaf: usize, best: &mut (u32, f32)) {
        let first_leaf = (1usize << self.depth) - 1;
        let mut node = first_leaf + leaf;
        self.scan(q, self.leaf_start[leaf] as usize, self.leaf_start[leaf + 1] as usize, best);
        // One stack for every subtree search (each leaves it empty).
        let mut stack = ([0u32; STACK], [0.0f32; STACK]);
        while node > 0 {
            let sibling = if node % 2 == 1 { node + 1 } else { node - 1 };
            if box_dist2(q, self.node_lo[sibling], self.node_hi[sibling]) <= best.1 {
                self.search_subtree(q, sibling, best, &mut stack);
            }
            node = (node - 1) / 2;
        }
    }

    /// [`search_from`](Self::search_from) inside the subtree `root` (its box already in reach):
    /// depth first, nearer child first, boxes strictly farther than the best pruned.
    #[inline]
    fn search_subtree(
        &self,
        q: [f32; 3],
        root: usize,
        best: &mut (u32, f32),
        (stack_node, stack_d2): &mut ([u32; STACK], [f32; STACK]),
    ) {
        let first_leaf = (1usize << self.depth) - 1;
        let mut sp = 0;
        let mut node = root;
        loop {
            if node >= first_leaf {
                let j = node - first_leaf;
                self.scan(q, self.leaf_start[j] as usize, self.leaf_start[j + 1] as usize, best);
            } else {
                let (l, r) = (2 * node + 1, 2 * node + 2);
                let dl = box_dist2(q, self.node_lo[l], self.node_hi[l]);
                let dr = box_dist2(q, self.node_lo[r], self.node_hi[r]);
                let (near, dn, far, df) = if dl <= dr { (l, dl, r, dr) } else { (r, dr, l, dl) };
                if df <= best.1 {
                    stack_node[sp] = far as u32;
                    stack_d2[sp] = df;
                    sp += 1;
                }
                if dn <= best.1 {
                    node = near;
                    continue;
                }
            }
            // Next pending subtree still in reach.
            loop {
                if sp == 0 {
                    return;
                }
                sp -= 1;
                if stack_d2[sp] <= best.1 {
                    node = stack_node[sp] as usize;
                    break;
                }
            }
        }
    }

    /// Scans the sorted points `p0..p1`, four at a time.
    #[inline(always)]
    fn scan(&self, q: [f32; 3], p0: usize, p1: usize, best: &mut (u32, f32)) {
        let (xs, ys, zs) = (&self.sorted[0][p0..p1], &self.sorted[1][p0..p1], &self.sorted[2][p0..p1]);
        let idx = &self.perm[p0..p1];
        let n = idx.len();
        if n < 4 {
            for k in 0..n {
                consider(best, dist2([xs[k], ys[k], zs[k]], q), idx[k]);
            }
            return;
        }
        let (qx, qy, qz) = (Vec4::splat(q[0]), Vec4::splat(q[1]), Vec4::splat(q[2]));
        let mut group = |at: usize| {
            let x = Vec4::from_slice(&xs[at..at + 4]) - qx;
            let y = Vec4::from_slice(&ys[at..at + 4]) - qy;
            let z = Vec4::from_slice(&zs[at..at + 4]) - qz;
            let d2 = x * x + y * y + z * z;
            if d2.min_element() <= best.1 {
                for (k, &d) in d2.to_array().iter().enumerate() {
                    consider(best, d, idx[at + k]);
                }
            }
        };
        let mut at = 0;
        while at + 4 <= n {
            group(at);
            at += 4;
        }
        if at < n {
            // The last four points, overlapping the group before: points seen twice change
            // nothing (same distance, same index).
            group(n - 4);
        }
    }

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

    /// As [`nearest_within`](Self::nearest_within) with one hint per query, or `hints` empty.
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
        check_batch(queries.len(), hints.len(), out.len())?;
        if !(radius >= 0.0 && radius.is_finite()) {
            return Err(Error::OutOfRange { what: "query radius", index: 0 });
        }
        for (i, (q, o)) in queries.iter().zip(out.iter_mut()).enumerate() {
            if !finite3(*q) {
                return Err(Error::NonFinite { what: "query point", index: i });
            }
            *o = self.nearest_within_one_hinted(*q, radius, hints.get(i).copied().unwrap_or(NONE));
        }
        Ok(())
    }

    /// For every query point (metres), the nearest point with no distance limit, see
    /// [`nearest_one`](Self::nearest_one). Allocates nothing.
    ///
    /// # Errors
    /// [`Error::Empty`] when the tree holds no point; [`Error::SizeMismatch`] when `out` is not as
    /// long as `queries`; [`Error::NonFinite`] for a NaN/Inf query coordinate (`out` is then
    /// partly written).
    pub fn nearest(&self, queries: &[[f32; 3]], out: &mut [Nearest]) -> Result<()> {
        self.nearest_hinted(queries, &[], out)
    }

    /// As [`nearest`](Self::nearest) with one hint per query, or `hints` empty.
    ///
    /// # Errors
    /// As [`nearest`](Self::nearest); [`Error::SizeMismatch`] for hints neither empty nor one per
    /// query.
    pub fn nearest_hinted(&self, queries: &[[f32; 3]], hints: &[u32], out: &mut [Nearest]) -> Result<()> {
        check_batch(queries.len(), hints.len(), out.len())?;
        if self.n_points == 0 {
            return Err(Error::Empty { what: "point tree" });
        }
        for (i, (q, o)) in queries.iter().zip(out.iter_mut()).enumerate() {
            if !finite3(*q) {
                return Err(Error::NonFinite { what: "query point", index: i });
            }
            let hint = hints.get(i).copied().unwrap_or(NONE);
            *o = self.nearest_one_hinted(*q, hint).unwrap_or(Nearest { index: 0, distance: f32::INFINITY });
        }
        Ok(())
    }
}

fn check_batch(queries: usize, hints: usize, out: usize) -> Result<()> {
    if out != queries {
        return Err(Error::SizeMismatch { what: "query output", expected: queries, got: out });
    }
    if hints != 0 && hints != queries {
        return Err(Error::SizeMismatch { what: "query hints", expected: queries, got: hints });
    }
    Ok(())
}

/// `min` as one `minss` (inputs are finite).
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// `max` as one `maxss`.
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// A search result as a [`Nearest`].
#[inline(always)]
fn found((i, d2): (u32, f32)) -> Option<Nearest> {
    (i != NONE).then(|| Nearest { index: i, distance: libm::sqrtf(d2) })
}

/// Takes `(i, d2)` if it is nearer, or as near with a lower index.
#[inline(always)]
fn consider(best: &mut (u32, f32), d2: f32, i: u32) {
    if d2 <= best.1 && (d2 < best.1 || i < best.0) {
        *best = (i, d2);
    }
}

/// `(dx² + dy²) + dz²`, the order every distance of this module uses.
#[inline(always)]
fn dist2(p: [f32; 3], q: [f32; 3]) -> f32 {
    let (dx, dy, dz) = (p[0] - q[0], p[1] - q[1], p[2] - q[2]);
    dx * dx + dy * dy + dz * dz
}

/// Squared distance from `q` to the box `[lo, hi]`, a lower bound of [`dist2`] for every point
/// in the box (same operations on per-axis gaps no larger than the point's).
#[inline(always)]
fn box_dist2(q: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> f32 {
    let g = |a: usize| fmax(fmax(lo[a] - q[a], q[a] - hi[a]), 0.0);
    let (dx, dy, dz) = (g(0), g(1), g(2));
    dx * dx + dy * dy + dz * dz
}
