//! The objective evaluated as tasks of an [`Executor`], with the same result bit for bit
//! whatever the executor's parallelism.
//!
//! Triangles and hinges are cut into a fixed number of chunks ([`CHUNKS`]), each scattering its
//! gradient into its own buffer, which spans only the vertices its elements touch (a band, for
//! garments whose faces are numbered in order); each vertex then adds the buffers that hold it,
//! in chunk order, and its own terms (inertia, gravity, collision, friction). Energies are summed
//! per chunk and per fixed block of [`BLOCK`] vertices, and those sums in order. So no sum depends
//! on how the executor runs the tasks. The per-element and per-vertex math is the terms' own (one
//! place each); only the order of the sums differs from [`Objective::eval`], within rounding.

use super::bending::hinge_bending;
use super::collision::vertex_collision;
use super::friction::vertex_friction;
use super::inertia::{inertia_total, vertex_gravity, vertex_inertia};
use super::stretching::face_stretching;
use super::{check_len, Cloth, Objective, StepInputs, Terms, GRAVITY};
use crate::error::{Error, Result};
use crate::exec::par::{first_error, split, Disjoint};
use crate::exec::Executor;
use crate::math::{add3, Real};
use alloc::vec;
use alloc::vec::Vec;
use core::ops::Range;

/// Vertices per energy block: the unit of the vertex sums' fixed order and of the task splits.
const BLOCK: usize = 256;
/// Chunks of triangles and hinges: the most threads the element pass can use.
pub const CHUNKS: usize = 8;
/// Most tasks the vertex pass is split into.
const MAX_TASKS: usize = 64;

/// Blocks of [`BLOCK`] covering `n` items.
fn blocks(n: usize) -> usize {
    n.div_ceil(BLOCK)
}

/// The items of blocks `b`, out of `n`.
fn items(b: Range<usize>, n: usize) -> Range<usize> {
    (b.start * BLOCK).min(n)..(b.end * BLOCK).min(n)
}

/// Buffers to evaluate an [`Objective`] on one garment as tasks of an [`Executor`] (see the
/// module docs), sized once for the garment's [`Cloth`]. Evaluation allocates nothing.
#[derive(Clone, Debug)]
pub struct ObjectiveTasks<T: Real> {
    n: usize,
    nf: usize,
    nh: usize,
    /// The vertices each chunk's elements touch: chunk `k` scatters vertex `v` into
    /// `scatter[offset[k] + v - window[k].start]`.
    window: [Range<usize>; CHUNKS],
    offset: [usize; CHUNKS + 1],
    /// Every chunk's gradient of stretching and bending over its window, J/m.
    scatter: Vec<[T; 3]>,
    /// Per chunk: stretching and bending energy, J.
    chunk_sum: [[T; 2]; CHUNKS],
    /// Per chunk: a vertex an element named outside the chunk's window (a cloth other than the
    /// one the buffers were made for, with the same counts).
    chunk_foreign: [Option<u32>; CHUNKS],
    /// Per block of vertices: inertia (before its common factor), gravity, collision (before
    /// its weight), friction.
    vertex_sum: Vec<[T; 4]>,
    /// The first error of each task.
    errors: Vec<Option<Error>>,
}

impl<T: Real> ObjectiveTasks<T> {
    /// Buffers for `cloth`'s garment.
    pub fn new(cloth: &Cloth<T>) -> ObjectiveTasks<T> {
        let n = cloth.n_vertices();
        let (nf, nh) = (cloth.faces.len(), cloth.hinges.len());
        let mut window: [Range<usize>; CHUNKS] = core::array::from_fn(|_| 0..0);
        let mut offset = [0; CHUNKS + 1];
        for k in 0..CHUNKS {
            let faces = cloth.faces[split(nf, CHUNKS, k)].iter().flatten();
            let hinges = cloth.hinges[split(nh, CHUNKS, k)].iter().flat_map(|h| h.edge.iter().chain(&h.opposite));
            let (lo, hi) =
                faces.chain(hinges).fold((usize::MAX, 0), |(lo, hi), &v| (lo.min(v as usize), hi.max(v as usize + 1)));
            window[k] = if lo < hi { lo..hi } else { 0..0 };
            offset[k + 1] = offset[k] + window[k].len();
        }
        ObjectiveTasks {
            n,
            nf,
            nh,
            window,
            offset,
            scatter: vec![[T::ZERO; 3]; offset[CHUNKS]],
            chunk_sum: [[T::ZERO; 2]; CHUNKS],
            chunk_foreign: [None; CHUNKS],
            vertex_sum: vec![[T::ZERO; 4]; blocks(n)],
            errors: vec![None; MAX_TASKS],
        }
    }

    /// As [`Objective::eval`] (`grad`, when given, is **overwritten**), with the work split into
    /// tasks of `exec`: the same terms within rounding, and the same bits for any executor.
    /// Allocates nothing.
    ///
    /// # Errors
    /// As [`Objective::eval`]; for a `cloth` other than the one these buffers were made for,
    /// [`Error::SizeMismatch`] (other counts) or, when the gradient is asked for,
    /// [`Error::OutOfRange`] (the same counts, another topology).
    pub fn eval(
        &mut self,
        exec: &dyn Executor,
        objective: &Objective,
        cloth: &Cloth<T>,
        inputs: &StepInputs<'_, T>,
        x: &[[T; 3]],
        grad: Option<&mut [[T; 3]]>,
    ) -> Result<Terms<T>> {
        let n = self.n;
        check_len("garment vertices of the task buffers", cloth.n_vertices(), n)?;
        check_len("triangles of the task buffers", cloth.faces.len(), self.nf)?;
        check_len("hinges of the task buffers", cloth.hinges.len(), self.nh)?;
        check_len("positions", x.len(), n)?;
        if let Some(g) = grad.as_deref() {
            check_len("gradient", g.len(), n)?;
        }
        if objective.inertia {
            check_len("current positions", inputs.pos.len(), n)?;
            check_len("velocities", inputs.velocity.len(), n)?;
        }
        if objective.collision.is_some() {
            let c = inputs.collision.ok_or(Error::Empty { what: "collision input" })?;
            check_len("nearest body faces", c.nearest.len(), n)?;
            check_len("body face normals", c.next.normals.len(), c.next.centroids.len())?;
        }
        if let Some(p) = &objective.friction {
            let f = inputs.friction.ok_or(Error::Empty { what: "friction input" })?;
            check_len("current positions", inputs.pos.len(), n)?;
            check_len("friction nearest faces (a)", f.nearest_a.len(), n)?;
            check_len("friction nearest faces (b)", f.nearest_b.len(), n)?;
            let nf = f.frame_a.centroids.len();
            for len in [f.frame_a.normals.len(), f.frame_b.centroids.len(), f.frame_b.normals.len()] {
                check_len("body face frames", len, nf)?;
            }
            if p.floor_axis > 2 {
                return Err(Error::IndexOutOfRange { what: "floor axis", at: 0, index: p.floor_axis, len: 3 });
            }
        }
        match grad {
            Some(g) => self.run::<true>(exec, objective, cloth, inputs, x, g),
            None => self.run::<false>(exec, objective, cloth, inputs, x, &mut []),
        }
    }

    /// The two passes (elements, then vertices) and the sums, once the inputs are checked.
    fn run<const GRAD: bool>(
        &mut self,
        exec: &dyn Executor,
        objective: &Objective,
        cloth: &Cloth<T>,
        inputs: &StepInputs<'_, T>,
        x: &[[T; 3]],
        grad: &mut [[T; 3]],
    ) -> Result<Terms<T>> {
        let (n, nf, nh) = (self.n, self.nf, self.nh);
        let (stretching, bending) = (objective.stretching, objective.bending);
        {
            let Self { window, offset, scatter, chunk_sum, chunk_foreign, .. } = &mut *self;
            let (window, offset) = (&*window, &*offset);
            let scatter = Disjoint::new(scatter);
            let sums = Disjoint::new(chunk_sum);
            let foreign = Disjoint::new(chunk_foreign);
            exec.run(CHUNKS, &|k| {
                // SAFETY: each chunk its own part of the buffer, its own sums and flag.
                let (g, sum, foreign) = unsafe {
                    (
                        scatter.range(offset[k]..offset[k + 1]),
                        &mut sums.range(k..k + 1)[0],
                        &mut foreign.range(k..k + 1)[0],
                    )
                };
                if GRAD {
                    g.iter_mut().for_each(|v| *v = [T::ZERO; 3]);
                }
                // Accumulated locally and stored once: the chunks' sums share cache lines.
                let mut energy = [T::ZERO; 2];
                let mut outside = None;
                let lo = window[k].start;
                let mut add = |v: u32, c: [T; 3]| match g.get_mut((v as usize).wrapping_sub(lo)) {
                    Some(at) => *at = add3(*at, c),
                    None => outside = Some(v),
                };
                if stretching {
                    for fi in split(nf, CHUNKS, k) {
                        let (e, c) = face_stretching::<T, GRAD>(cloth, fi, x);
                        energy[0] += e;
                        if GRAD {
                            for (&v, c) in cloth.faces[fi].iter().zip(c) {
                                add(v, c);
                            }
                        }
                    }
                }
                if bending {
                    for hi in split(nh, CHUNKS, k) {
                        let (e, c) = hinge_bending::<T, GRAD>(cloth, hi, x);
                        energy[1] += e;
                        if GRAD {
                            let h = &cloth.hinges[hi];
                            for (&v, c) in h.edge.iter().chain(&h.opposite).zip(c) {
                                add(v, c);
                            }
                        }
                    }
                }
                *sum = energy;
                *foreign = outside;
            });
        }
        let inv_dt2 = T::ONE / (inputs.dt * inputs.dt);
        let gacc = T::from_f64(GRAVITY);
        let collision = objective.collision.map(|p| (T::from_f64(p.eps), T::from_f64(p.weight)));
        let mu_g = objective.friction.map(|p| T::from_f64(p.mu * GRAVITY));
        {
            let Self { window, offset, scatter, vertex_sum, errors, .. } = self;
            let (window, offset, scatter) = (&*window, &*offset, &*scatter);
            let tasks = exec.parallelism().clamp(1, MAX_TASKS);
            errors.iter_mut().for_each(|e| *e = None);
            let grad = Disjoint::new(grad);
            let sums = Disjoint::new(vertex_sum);
            let errors = Disjoint::new(errors);
            let nbv = blocks(n);
            exec.run(tasks, &|t| {
                let b = split(nbv, tasks, t);
                let first = b.start * BLOCK;
                // SAFETY: tasks own disjoint block ranges, hence disjoint vertex ranges; each
                // task its own error slot.
                let (sums, g, error) = unsafe {
                    (
                        sums.range(b.clone()),
                        grad.range(if GRAD { items(b.clone(), n) } else { 0..0 }),
                        errors.range(t..t + 1),
                    )
                };
                for (k, s) in sums.iter_mut().enumerate() {
                    let mut e = [T::ZERO; 4];
                    for v in items((b.start + k)..(b.start + k + 1), n) {
                        let mut gv = [T::ZERO; 3];
                        if GRAD && (stretching || bending) {
                            for k in 0..CHUNKS {
                                if window[k].contains(&v) {
                                    gv = add3(gv, scatter[offset[k] + v - window[k].start]);
                                }
                            }
                        }
                        let m = cloth.mass[v];
                        if objective.inertia {
                            let (ev, gi) = vertex_inertia(m, inputs.pos[v], inputs.velocity[v], inv_dt2, x[v]);
                            e[0] += ev;
                            gv = add3(gv, gi);
                        }
                        if objective.gravity {
                            let (ev, gy) = vertex_gravity(m, gacc, x[v]);
                            e[1] += ev;
                            gv[1] += gy;
                        }
                        if let (Some((eps, weight)), Some(c)) = (collision, inputs.collision) {
                            let f = c.nearest[v] as usize;
                            let nfb = c.next.centroids.len();
                            if f >= nfb {
                                error[0] = Some(Error::IndexOutOfRange {
                                    what: "nearest body face",
                                    at: v,
                                    index: f,
                                    len: nfb,
                                });
                                return;
                            }
                            let (ev, gc) = vertex_collision(x[v], f, c.next, eps, weight);
                            e[2] += ev;
                            gv = add3(gv, gc);
                        }
                        if let (Some(k), Some(p), Some(fr)) = (mu_g, &objective.friction, inputs.friction) {
                            let (u, w) = (fr.nearest_a[v] as usize, fr.nearest_b[v] as usize);
                            let nfb = fr.frame_a.centroids.len();
                            if u >= nfb || w >= nfb {
                                error[0] = Some(Error::IndexOutOfRange {
                                    what: "friction nearest body face",
                                    at: v,
                                    index: u.max(w),
                                    len: nfb,
                                });
                                return;
                            }
                            let (ev, gf) =
                                vertex_friction(k * m, inputs.pos[v], x[v], [u, w], fr.frame_a, fr.frame_b, p);
                            e[3] += ev;
                            gv = add3(gv, gf);
                        }
                        if GRAD {
                            g[v - first] = gv;
                        }
                    }
                    *s = e;
                }
            });
        }
        if let Some(v) = self.chunk_foreign.iter().flatten().next() {
            return Err(Error::OutOfRange {
                what: "garment vertex (task buffers made for another garment)",
                index: *v as usize,
            });
        }
        first_error(&mut self.errors)?;
        let mut t = Terms::<T>::default();
        for s in &self.chunk_sum {
            t.stretching += s[0];
            t.bending += s[1];
        }
        let mut v = [T::ZERO; 4];
        for s in &self.vertex_sum {
            for k in 0..4 {
                v[k] += s[k];
            }
        }
        if objective.inertia {
            t.inertia = inertia_total(v[0], inv_dt2);
        }
        t.gravity = v[1];
        if let Some((_, weight)) = collision {
            t.collision = v[2] * weight;
        }
        t.friction = v[3];
        Ok(t)
    }
}
