//! Scoring one step: the body's faces at the frames a step reads, the objective's terms,
//! penetration, strain and speed of a prediction, the converged implicit step it is compared
//! with (the [`Gap`]) and the count of vertices inside the body.

use super::{Animation, FrameRecord, Gap, StepKind};
use crate::body::{BodyMesh, PointGrid, Winding};
use crate::error::Result;
use crate::features::DT;
use crate::math::{norm3, sub3};
use crate::physics::{
    face_frames, max_edge_strains, plane_distances, quarter_median_edge_length, CentroidQuery, Cloth, FaceFrame,
    Objective,
};
use crate::physics::{Terms, PENETRATION_DEPTH};
use crate::sim::SimState;
use crate::solve::{ImplicitStep, LbfgsParams, LbfgsReport, Query, StepBody, StepState};
use alloc::vec;
use alloc::vec::Vec;

/// One body frame's faces: f64 centroids and normals for the terms, a grid over the (f32)
/// centroids for the nearest-face queries.
struct BodySlot {
    frame: usize,
    centroids: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    centroids32: Vec<[f32; 3]>,
    grid: PointGrid,
}

/// The body at the frames a step reads (previous, current, next), each computed once.
struct BodyRing {
    faces: Vec<[u32; 3]>,
    slots: [BodySlot; 3],
}

impl BodyRing {
    fn new(mesh: &BodyMesh) -> Result<BodyRing> {
        let nf = mesh.n_faces();
        let slot = || -> Result<BodySlot> {
            Ok(BodySlot {
                frame: usize::MAX,
                centroids: vec![[0.0; 3]; nf],
                normals: vec![[0.0; 3]; nf],
                centroids32: vec![[0.0; 3]; nf],
                grid: PointGrid::new(nf.max(1), (8 * nf).max(64))?,
            })
        };
        Ok(BodyRing { faces: mesh.faces().to_vec(), slots: [slot()?, slot()?, slot()?] })
    }

    /// The slot holding frame `f` of `anim`, computing it over a slot not in `keep`.
    fn ensure(&mut self, anim: &dyn Animation, f: usize, keep: &[usize]) -> Result<usize> {
        if let Some(i) = self.slots.iter().position(|s| s.frame == f) {
            return Ok(i);
        }
        let i = self.slots.iter().position(|s| !keep.contains(&s.frame)).unwrap_or(0);
        let s = &mut self.slots[i];
        s.frame = usize::MAX;
        face_frames(anim.body_frame(f), &self.faces, &mut s.centroids, &mut s.normals)?;
        for (c32, c) in s.centroids32.iter_mut().zip(&s.centroids) {
            *c32 = c.map(|v| v as f32);
        }
        s.grid.rebuild(&s.centroids32)?;
        s.frame = f;
        Ok(i)
    }

    fn face_frame(&self, i: usize) -> FaceFrame<'_, f64> {
        FaceFrame { centroids: &self.slots[i].centroids, normals: &self.slots[i].normals }
    }
}

/// Scores steps of one garment: the f64 cloth constants, the implicit step's workspace and the
/// step's state in f64.
pub(super) struct Scorer {
    cloth: Cloth<f64>,
    /// The shortest edge of the long-edge strain, m ([`quarter_median_edge_length`]).
    long_edge: f64,
    pub(super) objective: Objective,
    solver: ImplicitStep<f64>,
    ring: Option<BodyRing>,
    pinned: Vec<bool>,
    pos: Vec<[f64; 3]>,
    vel: Vec<[f64; 3]>,
    targets: Vec<[f64; 3]>,
    pub(super) x: Vec<[f64; 3]>,
    pub(super) x_star: Vec<[f64; 3]>,
    pos32: Vec<[f32; 3]>,
    near: Vec<u32>,
    dist: Vec<f64>,
}

impl Scorer {
    pub(super) fn new(anim: &dyn Animation, objective: &Objective) -> Result<Scorer> {
        let g = anim.garment();
        let n = g.n_vertices();
        let mut objective = *objective;
        let ring = match anim.body_mesh() {
            Some(m) => Some(BodyRing::new(m)?),
            None => {
                objective.collision = None;
                objective.friction = None;
                None
            }
        };
        let z = vec![[0.0f64; 3]; n];
        let cloth = Cloth::new(g);
        Ok(Scorer {
            long_edge: quarter_median_edge_length(&cloth),
            cloth,
            objective,
            solver: ImplicitStep::new(n, 10),
            ring,
            pinned: g.pinned().to_vec(),
            pos: z.clone(),
            vel: z.clone(),
            targets: z.clone(),
            x: z.clone(),
            x_star: z,
            pos32: vec![[0.0; 3]; n],
            near: vec![0; n],
            dist: vec![0.0; n],
        })
    }

    /// Loads the step's start state: `before` as the runtime saw it (pinned vertices at their
    /// targets with zero velocity), or, after the start-up step, the state it left.
    pub(super) fn load(
        &mut self,
        kind: StepKind,
        before: &SimState,
        targets: &[[f32; 3]],
        x: &[[f32; 3]],
        v: &[[f32; 3]],
    ) {
        self.load_parts(kind, &before.pos, &before.velocity, targets, x, v);
    }

    /// [`Scorer::load`] from the state's positions and velocities.
    pub(super) fn load_parts(
        &mut self,
        kind: StepKind,
        before_pos: &[[f32; 3]],
        before_vel: &[[f32; 3]],
        targets: &[[f32; 3]],
        x: &[[f32; 3]],
        v: &[[f32; 3]],
    ) {
        let to64 = |p: [f32; 3]| p.map(|c| c as f64);
        for i in 0..self.pos.len() {
            self.targets[i] = to64(targets[i]);
            self.x[i] = to64(x[i]);
            if self.pinned[i] {
                self.pos[i] = self.targets[i];
                self.vel[i] = [0.0; 3];
            } else if kind == StepKind::StartUp {
                // x = p + v_s + a and v = v_s + a, so the start-up left p = x - v, v_s = p - p0.
                self.pos[i] = sub3(self.x[i], to64(v[i]));
                self.vel[i] = sub3(self.pos[i], to64(before_pos[i]));
            } else {
                self.pos[i] = to64(before_pos[i]);
                self.vel[i] = to64(before_vel[i]);
            }
        }
    }

    /// The record of the loaded and scored step (strain and speed of the prediction).
    pub(super) fn record(
        &self,
        frame: usize,
        kind: StepKind,
        terms: Option<Terms<f64>>,
        penetrating_percent: f64,
        step_ms: f64,
        gap: Option<Gap>,
    ) -> FrameRecord {
        let [max_edge_strain, max_long_edge_strain] = max_edge_strains(&self.cloth, &self.x, self.long_edge);
        let max_speed =
            self.x.iter().zip(&self.pos).map(|(a, b)| norm3(sub3(*a, *b))).fold(0.0f64, f64::max) / DT as f64;
        FrameRecord {
            frame,
            kind,
            terms,
            penetrating_percent,
            max_edge_strain,
            max_long_edge_strain,
            max_speed,
            step_ms,
            gap,
            inside_percent: None,
            off_body: None,
            over_budget: false,
        }
    }

    /// The ring slots of body frames `[previous, current, next]` (`None` without a body).
    fn body_slots(&mut self, anim: &dyn Animation, frames: [usize; 3]) -> Result<Option<[usize; 3]>> {
        let [fp, fc, fnx] = frames;
        let Some(ring) = &mut self.ring else { return Ok(None) };
        let c = ring.ensure(anim, fc, &[fc])?;
        let nx = ring.ensure(anim, fnx, &[fc, fnx])?;
        let p = ring.ensure(anim, fp, &[fc, fnx, fp])?;
        Ok(Some([p, c, nx]))
    }

    /// The implicit step (L-BFGS under `params`, from the coasting guess) of the loaded state
    /// into `x`: the implicit solver as a simulator.
    pub(super) fn implicit(
        &mut self,
        anim: &dyn Animation,
        frames: [usize; 3],
        params: &LbfgsParams,
    ) -> Result<LbfgsReport> {
        let idx = self.body_slots(anim, frames)?;
        let body = step_body(self.ring.as_ref(), idx);
        let state = StepState {
            pos: &self.pos,
            velocity: &self.vel,
            dt: DT as f64,
            pinned: &self.pinned,
            targets: &self.targets,
        };
        self.solver.step(&self.cloth, &self.objective, &state, body.as_ref(), params, &mut self.x)
    }

    /// Scores the loaded step: terms, penetration, strain, speed and (if asked) the gap.
    pub(super) fn score(
        &mut self,
        anim: &dyn Animation,
        frames: [usize; 3],
        with_terms: bool,
        gap: Option<&LbfgsParams>,
    ) -> Result<(Option<Terms<f64>>, f64, Option<Gap>)> {
        let idx = self.body_slots(anim, frames)?;
        let mut penetrating = 0.0;
        if let (Some(ring), Some([_, c, nx])) = (&self.ring, idx) {
            for (o, p) in self.pos32.iter_mut().zip(&self.pos) {
                *o = p.map(|c| c as f32);
            }
            ring.slots[c].grid.nearest_into(&self.pos32, &mut self.near);
            plane_distances(&self.x, &self.near, ring.face_frame(nx), &mut self.dist);
            let count = self.dist.iter().filter(|&&d| d < PENETRATION_DEPTH).count();
            penetrating = 100.0 * count as f64 / self.dist.len().max(1) as f64;
        }
        if !with_terms {
            return Ok((None, penetrating, None));
        }
        let body = step_body(self.ring.as_ref(), idx);
        let state = StepState {
            pos: &self.pos,
            velocity: &self.vel,
            dt: DT as f64,
            pinned: &self.pinned,
            targets: &self.targets,
        };
        let terms = self.solver.evaluate(&self.cloth, &self.objective, &state, body.as_ref(), &self.x)?;
        let gap = match gap {
            Some(params) => Some(self.optimum(anim, frames, params)?.gap(terms.total())),
            None => None,
        };
        Ok((Some(terms), penetrating, gap))
    }

    /// The converged implicit step of the loaded state (L-BFGS under `params` on the scoring
    /// objective, from the coasting guess) into `x_star`, with its terms.
    pub(super) fn optimum(
        &mut self,
        anim: &dyn Animation,
        frames: [usize; 3],
        params: &LbfgsParams,
    ) -> Result<Optimum> {
        let idx = self.body_slots(anim, frames)?;
        let body = step_body(self.ring.as_ref(), idx);
        let state = StepState {
            pos: &self.pos,
            velocity: &self.vel,
            dt: DT as f64,
            pinned: &self.pinned,
            targets: &self.targets,
        };
        let r = self.solver.step(&self.cloth, &self.objective, &state, body.as_ref(), params, &mut self.x_star)?;
        let terms = self.solver.evaluate(&self.cloth, &self.objective, &state, body.as_ref(), &self.x_star)?;
        Ok(Optimum { report: r, terms })
    }
}

/// The converged implicit step of one state: what a step's objective is compared with.
pub(super) struct Optimum {
    report: LbfgsReport,
    /// Terms at the optimum (their total is `report.f`).
    terms: Terms<f64>,
}

impl Optimum {
    /// The gap of a step whose objective is `model` (J), from the same state.
    pub(super) fn gap(&self, model: f64) -> Gap {
        let r = &self.report;
        let descent = r.f_start - r.f;
        let relative = (descent > 1e-12 * r.f_start.abs().max(1e-3)).then(|| (model - r.f) / descent);
        Gap {
            model,
            optimum: r.f,
            optimum_terms: self.terms,
            coasting: r.f_start,
            relative,
            iterations: r.iterations,
            converged: r.converged(),
        }
    }
}

/// Counts the garment vertices inside the body on the frames [`RolloutOptions::inside_every`](super::RolloutOptions::inside_every)
/// picks.
pub(super) struct InsideCounter {
    winding: Winding,
    every: usize,
}

impl InsideCounter {
    /// `None` when the option is off or there is no body.
    pub(super) fn new(anim: &dyn Animation, every: usize) -> Result<Option<InsideCounter>> {
        match anim.body_mesh() {
            Some(mesh) if every > 0 => {
                Ok(Some(InsideCounter { winding: Winding::new(mesh, anim.body_frame(0))?, every }))
            }
            _ => Ok(None),
        }
    }

    /// % of `garment` (m) inside the body at frame `t`, if `t` is one of the picked frames.
    pub(super) fn count(
        this: &mut Option<Self>,
        anim: &dyn Animation,
        t: usize,
        garment: &[[f32; 3]],
    ) -> Result<Option<f64>> {
        let (Some(c), Some(mesh)) = (this, anim.body_mesh()) else { return Ok(None) };
        if !t.is_multiple_of(c.every) {
            return Ok(None);
        }
        c.winding.refit(mesh, anim.body_frame(t))?;
        Ok(Some(100.0 * c.winding.count_inside(garment) as f64 / garment.len().max(1) as f64))
    }
}
/// The body of a step from the ring slots `[previous, current, next]`.
fn step_body(ring: Option<&BodyRing>, idx: Option<[usize; 3]>) -> Option<StepBody<'_, f64>> {
    let (ring, [p, c, nx]) = (ring?, idx?);
    Some(StepBody {
        prev: ring.face_frame(p),
        current: ring.face_frame(c),
        next: ring.face_frame(nx),
        query_prev: &ring.slots[p].grid as &Query,
        query_current: &ring.slots[c].grid,
        query_next: &ring.slots[nx].grid,
    })
}
