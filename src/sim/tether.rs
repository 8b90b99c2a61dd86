//! Body tethers: an optional post-step limit on how far each worn garment vertex may move from
//! the body vertex it was put on. Not part of HOOD, and not physics: the "max distance"
//! constraint of game-engine cloth, for scenes where the garment must stay on whatever the step
//! does (a top upside down in a handstand slides off over the head under the physics objective,
//! with the solver as with the networks).
//!
//! At the first step (and the first after [`Sim::set_state`](super::Sim::set_state), which places
//! the garment anew), every free garment vertex within [`TETHER_REACH`] of a body vertex is tied
//! to the nearest one, with a length of that distance plus the slack. After every step a vertex
//! farther than its length from its body vertex (at the new frame) is pulled straight back to that
//! length, and its velocity takes the move, so the next step starts from where it was put. When no
//! vertex is beyond its length (and the projection, when on, moved none) nothing is touched: a
//! garment that stays on is stepped exactly as without tethers.
//!
//! The cloth around a pulled vertex follows it. Neighbours are tied to different body vertices
//! at different distances, so a step that carries the cloth away pulls some vertices back and
//! not the one 2 mm beside them: moved alone, a sleeve's 2 mm seam edge was stretched to 16 mm.
//! So after the pulls, every edge with a moved end that is longer than its rest length by more
//! than [`TETHER_FOLLOW_STRETCH`] is shortened to that length by moving the end that moved less
//! (a neighbour pulled by less, or not at all), and so on outward: position-based dynamics'
//! strain limit, but only where the tethers moved something (the step's own stretching elsewhere
//! is left as it is). A last pass brings any vertex that following carried beyond its own length
//! back onto it.
//!
//! With the collision projection on, it runs first and its moves count as the pulls' do: the
//! cloth follows a vertex pushed out of the body as it follows one pulled back (each vertex is
//! pushed along its own nearest face, and neighbours pushed out of different faces pull apart).
//! The pass then runs whenever the projection or a tether moved something.

use crate::body::{Nearest, PointGrid};
use crate::error::{Error, Result};
use crate::math::{add3, dot3, norm3, scale3, sub3};
use crate::mesh::Garment;
use alloc::vec;
use alloc::vec::Vec;

/// Farthest a garment vertex may be from every body vertex when the sim is made (m) and still
/// be tethered: beyond it the vertex is not worn on the body (a cape's hem, a long skirt below
/// the knees) and moves freely.
pub const TETHER_REACH: f32 = 0.1;

/// Default tether slack (m): how much farther than where it was put a worn vertex may move from
/// its body vertex. Enough for a shirt to ride up a hand's width; the off-body test of the
/// evaluation counts a vertex off at 10 cm from the body.
pub const DEFAULT_TETHER_SLACK: f32 = 0.05;

/// Largest tether slack accepted (m).
pub const MAX_TETHER_SLACK: f32 = 1.0;

/// Stretch (fraction of its rest length) an edge from a vertex the tethers moved may keep; a
/// longer one brings its other end along. A third of the largest strain the evaluation accepts
/// (1.5), and enough give that a pull fades within a few edges: at 0.1 a 4 cm pull dragged cloth
/// 40 cm away, where pulls in other directions fought it.
pub const TETHER_FOLLOW_STRETCH: f32 = 0.5;

/// Most sweeps over the edges that bring the cloth along after the pulls (each carries the move
/// at least one edge further; cloth farther than that is left where the step put it).
const MAX_FOLLOW_SWEEPS: usize = 64;

/// Excess length (m) below which an edge is left as it is, so that the sweeps end.
const FOLLOW_TOLERANCE: f32 = 1e-6;

/// No tether for this vertex (pinned, or out of reach).
const UNTETHERED: u32 = u32::MAX;

/// The tethers of one garment on one body, with the buffers to tie them without allocating.
#[derive(Clone, Debug)]
pub(super) struct Tethers {
    /// Slack, m.
    slack: f32,
    /// Whether the ties are made (from the state the first step started from).
    tied: bool,
    /// The body's vertices, to find each garment vertex's nearest when tying.
    grid: PointGrid,
    nearest: Vec<Option<Nearest>>,
    /// Body vertex of every garment vertex ([`UNTETHERED`]: none).
    anchor: Vec<u32>,
    /// Largest distance from the anchor (m): the distance when tied plus the slack.
    length: Vec<f32>,
    /// Whether each vertex may be moved (not pinned), as when tied.
    free: Vec<bool>,
    /// The garment's edges and their rest lengths (m), along which the cloth follows.
    edges: Vec<[u32; 2]>,
    rest_len: Vec<f32>,
    /// Where each vertex was before this step's pulls (m).
    before: Vec<[f32; 3]>,
    /// Where each vertex was before this step's effects (m): before the collision projection
    /// when it moved some ([`start`](Self::start)), else `before`. The cloth follows every move
    /// since.
    start: Vec<[f32; 3]>,
    /// Vertices moved by the last [`apply`](Self::apply).
    moved: usize,
}

impl Tethers {
    /// Untied tethers for `garment` on a body of `n_body` vertices, with `slack` metres to spare
    /// (allocates, once, when the sim is made).
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for a slack that is negative, not finite or above
    /// [`MAX_TETHER_SLACK`]; errors of the grid.
    pub(super) fn new(garment: &Garment, n_body: usize, slack: f32) -> Result<Tethers> {
        if !(0.0..=MAX_TETHER_SLACK).contains(&slack) {
            return Err(Error::OutOfRange { what: "tether slack (0 <= m <= MAX_TETHER_SLACK)", index: 0 });
        }
        let n_garment = garment.n_vertices();
        let rest = garment.rest();
        let edges = garment.edges().to_vec();
        let rest_len = edges.iter().map(|&[i, j]| norm3(sub3(rest[i as usize], rest[j as usize]))).collect();
        Ok(Tethers {
            slack,
            tied: false,
            grid: PointGrid::new(n_body, (n_body * 4).max(64))?,
            nearest: vec![None; n_garment],
            anchor: vec![UNTETHERED; n_garment],
            length: vec![0.0; n_garment],
            free: vec![false; n_garment],
            edges,
            rest_len,
            before: vec![[0.0; 3]; n_garment],
            start: vec![[0.0; 3]; n_garment],
            moved: 0,
        })
    }

    /// Whether the ties are made.
    pub(super) fn tied(&self) -> bool {
        self.tied
    }

    /// Unties: the next step ties again (the garment was placed anew).
    pub(super) fn untie(&mut self) {
        self.tied = false;
    }

    /// Ties every free vertex of `garment` (m) within [`TETHER_REACH`] of a vertex of `body` (m,
    /// the same frame) to the nearest one. Allocates nothing.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `garment` or `pinned` is not one per garment vertex, errors of
    /// the grid (a body of more vertices than it was made for, non-finite positions); the ties
    /// are then left unmade.
    pub(super) fn tie(&mut self, garment: &[[f32; 3]], pinned: &[bool], body: &[[f32; 3]]) -> Result<()> {
        let n = self.anchor.len();
        for (what, len) in [("tethered garment positions", garment.len()), ("pinned flags", pinned.len())] {
            if len != n {
                return Err(Error::SizeMismatch { what, expected: n, got: len });
            }
        }
        self.tied = false;
        self.grid.rebuild(body)?;
        self.grid.nearest_within(garment, TETHER_REACH, &mut self.nearest)?;
        for (i, near) in self.nearest.iter().enumerate() {
            (self.anchor[i], self.length[i]) = match (pinned[i], near) {
                (false, Some(Nearest { index, distance })) => (*index, distance + self.slack),
                _ => (UNTETHERED, 0.0),
            };
        }
        self.free.iter_mut().zip(pinned).for_each(|(f, &p)| *f = !p);
        self.tied = true;
        Ok(())
    }

    /// Garment vertices that have a tether.
    pub(super) fn count(&self) -> usize {
        if !self.tied {
            return 0;
        }
        self.anchor.iter().filter(|&&a| a != UNTETHERED).count()
    }

    /// Vertices moved by the last step.
    pub(super) fn moved(&self) -> usize {
        self.moved
    }

    /// Puts back the count `moved` of the last step that ran (a refused step changed it).
    pub(super) fn restore_last(&mut self, moved: usize) {
        self.moved = moved;
    }

    /// Forgets the last count (no step ran from the sim's state).
    pub(super) fn forget_last(&mut self) {
        self.moved = 0;
    }

    /// Records `pos` (m) as where this step's effects start: the moves made between this and
    /// [`apply`](Self::apply) (the collision projection's) are followed by the cloth as the
    /// pulls are, when `apply` is told that some were made. Allocates nothing.
    pub(super) fn start(&mut self, pos: &[[f32; 3]]) {
        if self.tied {
            self.start.copy_from_slice(pos);
        }
    }

    /// Pulls every tethered vertex of `pos` (m) that is farther than its length from its body
    /// vertex in `body` (m, the frame `pos` belongs to) straight back to that length, brings the
    /// cloth around it along (see the module notes), and adds every move to `velocity`
    /// (m/frame). `projected`: whether the collision projection moved vertices since
    /// [`start`](Self::start) recorded this step's start (the cloth then follows those moves
    /// too; never without that record). Allocates nothing.
    pub(super) fn apply(
        &mut self,
        body: &[[f32; 3]],
        pos: &mut [[f32; 3]],
        velocity: &mut [[f32; 3]],
        projected: bool,
    ) {
        self.moved = 0;
        if !self.tied {
            return;
        }
        self.before.copy_from_slice(pos);
        if !projected {
            self.start.copy_from_slice(pos);
        }
        if !self.pull_back(body, pos) && !projected {
            return;
        }
        self.follow(pos);
        self.pull_back(body, pos);
        let mut moved = 0;
        for (v, (x, &x0)) in velocity.iter_mut().zip(pos.iter().zip(&self.before)) {
            if *x != x0 {
                *v = add3(*v, sub3(*x, x0));
                moved += 1;
            }
        }
        self.moved = moved;
    }

    /// Moves every tethered vertex of `pos` (m) farther than its length from its body vertex in
    /// `body` (m) straight back to that length; whether any moved.
    fn pull_back(&self, body: &[[f32; 3]], pos: &mut [[f32; 3]]) -> bool {
        let mut any = false;
        for (i, (&a, &len)) in self.anchor.iter().zip(&self.length).enumerate() {
            // A body of another length cannot reach here (the sim checks every frame), but an
            // index past it is skipped rather than trusted.
            let Some(&b) = body.get(a as usize) else { continue };
            let d = sub3(pos[i], b);
            let dist2 = dot3(d, d);
            if dist2 <= len * len {
                continue;
            }
            pos[i] = add3(b, scale3(d, len / libm::sqrtf(dist2)));
            any = true;
        }
        any
    }

    /// Brings the cloth along after the pulls: sweeps the edges both ways (at most
    /// [`MAX_FOLLOW_SWEEPS`] times), shortening every edge with a moved end to its rest length
    /// times 1 + [`TETHER_FOLLOW_STRETCH`]. The end moved less so far gives way to the other
    /// (both halfway when they moved alike); pinned vertices do not move.
    fn follow(&self, pos: &mut [[f32; 3]]) {
        let moved2 = |pos: &[[f32; 3]], i: usize| {
            let d = sub3(pos[i], self.start[i]);
            dot3(d, d)
        };
        for sweep in 0..MAX_FOLLOW_SWEEPS {
            let mut changed = false;
            let mut relax = |k: usize| {
                let [i, j] = self.edges[k].map(|v| v as usize);
                let (mi, mj) = (moved2(pos, i), moved2(pos, j));
                if mi == 0.0 && mj == 0.0 {
                    return; // the step's own stretch
                }
                let d = sub3(pos[j], pos[i]);
                let len = libm::sqrtf(dot3(d, d));
                let excess = len - self.rest_len[k] * (1.0 + TETHER_FOLLOW_STRETCH);
                if excess <= FOLLOW_TOLERANCE {
                    return;
                }
                // Each end's share of the shortening, i's toward j and j's toward i.
                let (si, sj) = match (self.free[i], self.free[j]) {
                    (false, false) => return,
                    (true, false) => (1.0, 0.0),
                    (false, true) => (0.0, 1.0),
                    _ if mi < mj => (1.0, 0.0),
                    _ if mj < mi => (0.0, 1.0),
                    _ => (0.5, 0.5),
                };
                let toward_j = scale3(d, excess / len);
                pos[i] = add3(pos[i], scale3(toward_j, si));
                pos[j] = sub3(pos[j], scale3(toward_j, sj));
                changed = true;
            };
            if sweep % 2 == 0 {
                (0..self.edges.len()).for_each(&mut relax);
            } else {
                (0..self.edges.len()).rev().for_each(&mut relax);
            }
            if !changed {
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::grid;

    /// Distance between two points (m).
    fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
        norm3(sub3(a, b))
    }

    /// The largest strain (length over rest length, less 1) of the tethers' edges in `pos` (m).
    fn largest_strain(t: &Tethers, pos: &[[f32; 3]]) -> f32 {
        (t.edges.iter().zip(&t.rest_len))
            .map(|(&[i, j], &rest)| dist(pos[i as usize], pos[j as usize]) / rest - 1.0)
            .fold(0.0f32, f32::max)
    }

    /// A garment of `rest` (m) and `faces`.
    fn garment(rest: &[[f32; 3]], faces: &[[u32; 3]]) -> Garment {
        Garment::new(crate::mesh::GarmentDesc::new(rest, faces)).unwrap()
    }

    /// Each free vertex in reach is tied to its nearest body vertex with its distance plus the
    /// slack; pinned and far vertices are not; a vertex beyond its length comes back to it along
    /// the line to its body vertex, its velocity taking the move, and one within it stays (as
    /// does every edge the pull leaves within its stretch).
    #[test]
    fn tethers_pull_back_only_what_went_beyond_its_length() {
        let body = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let placed = [[0.0, 0.02, 0.0], [1.0, 0.0, 0.05], [0.0, 1.0, 0.01], [0.5, 0.5, 0.5]];
        let pinned = [false, false, true, false];
        let mut t = Tethers::new(&garment(&placed, &[[0, 1, 3], [1, 2, 3]]), body.len(), 0.03).unwrap();
        assert!(!t.tied());
        t.tie(&placed, &pinned, &body).unwrap();
        assert!(t.tied());
        assert_eq!(t.anchor, [0, 1, UNTETHERED, UNTETHERED]);
        assert!((t.length[0] - 0.05).abs() < 1e-6 && (t.length[1] - 0.08).abs() < 1e-6);
        assert_eq!(t.count(), 2);

        // The body moves 1 m along x; vertex 0 stays behind, vertex 1 follows, the pinned and the
        // untethered vertices go anywhere.
        let body_next: Vec<[f32; 3]> = body.iter().map(|p| [p[0] + 1.0, p[1], p[2]]).collect();
        let mut pos = [[0.0, 0.02, 0.0], [2.0, 0.0, 0.05], [5.0, 5.0, 5.0], [1.4, 0.5, 0.5]];
        let mut vel = [[0.1, 0.0, 0.0]; 4];
        let before = pos;
        t.apply(&body_next, &mut pos, &mut vel, false);
        assert_eq!(t.moved(), 1);
        assert!((dist(pos[0], body_next[0]) - t.length[0]).abs() < 1e-6);
        // Straight back: on the segment from where it was to its body vertex.
        let (a, b) = (sub3(before[0], body_next[0]), sub3(pos[0], body_next[0]));
        assert!((dot3(a, b) / (libm::sqrtf(dot3(a, a)) * libm::sqrtf(dot3(b, b))) - 1.0).abs() < 1e-6);
        for k in 0..3 {
            let v0 = if k == 0 { 0.1 } else { 0.0 };
            assert!((vel[0][k] - (v0 + pos[0][k] - before[0][k])).abs() < 1e-6);
        }
        assert_eq!(&pos[1..], &before[1..]);
        assert_eq!(vel[1], [0.1, 0.0, 0.0]);
        t.forget_last();
        assert_eq!(t.moved(), 0);
    }

    /// A strip of cloth 1 cm over a body, its first column tied half as far: slid 4 cm along
    /// the body, the first column is pulled back farther than the second, and the rest of the
    /// strip follows it instead of stretching the edges between them to half as long again.
    #[test]
    fn the_cloth_follows_a_vertex_pulled_farther_than_its_neighbours() {
        let (placed, faces) = grid(11, 2, 0.1, 0.01, 0.01);
        let first = |p: &[f32; 3]| p[0] < -0.049;
        let body: Vec<[f32; 3]> = placed.iter().map(|p| [p[0], if first(p) { 0.005 } else { 0.0 }, p[2]]).collect();
        let g = garment(&placed, &faces);
        let mut t = Tethers::new(&g, body.len(), 0.0).unwrap();
        t.tie(&placed, &[false; 22], &body).unwrap();
        let slid: Vec<[f32; 3]> = placed.iter().map(|p| [p[0] + 0.04, p[1], p[2]]).collect();

        // Pulled alone, the edges from the first column would be 1.5 times their rest length.
        let mut alone = slid.clone();
        assert!(t.pull_back(&body, &mut alone));
        assert!(largest_strain(&t, &alone) > 0.45, "{}", largest_strain(&t, &alone));

        let (mut pos, mut vel) = (slid.clone(), vec![[0.0; 3]; 22]);
        t.apply(&body, &mut pos, &mut vel, false);
        assert_eq!(t.moved(), 22);
        assert!(largest_strain(&t, &pos) <= TETHER_FOLLOW_STRETCH + 1e-4, "{}", largest_strain(&t, &pos));
        for (i, x) in pos.iter().enumerate() {
            assert!(dist(*x, body[i]) <= t.length[i] * (1.0 + 1e-5), "vertex {i} beyond its length");
            assert!((0..3).all(|k| (vel[i][k] - (x[k] - slid[i][k])).abs() < 1e-6), "velocity takes the move");
        }
        // Followed by less with distance from the first column, and never ahead of a pull alone.
        let back = |i: usize| slid[i][0] - pos[i][0];
        assert!(back(0) > back(1) && back(1) > back(5) && back(5) >= back(10) - 1e-6);
        assert!((1..11).all(|i| pos[i][0] <= alone[i][0] + 1e-6));
    }

    /// With the collision projection on, the cloth follows its moves as it follows the pulls:
    /// a vertex of a strip pushed 3 cm out (as the projection moves one out of the body) brings
    /// its neighbours along, though no tether pulls; the velocities take only the follow's moves
    /// (the projection added its own). When the projection moved nothing, the same positions
    /// are left as they are: the step's own stretch.
    #[test]
    fn the_cloth_follows_the_projections_moves() {
        let (placed, faces) = grid(11, 2, 0.1, 0.01, 0.01);
        let body: Vec<[f32; 3]> = placed.iter().map(|p| [p[0], 0.0, p[2]]).collect();
        let g = garment(&placed, &faces);
        let mut t = Tethers::new(&g, body.len(), 0.1).unwrap();
        t.tie(&placed, &[false; 22], &body).unwrap();
        let mut projected = placed.clone();
        projected[5][1] += 0.03;
        assert!(largest_strain(&t, &projected) > 1.5, "{}", largest_strain(&t, &projected));

        let (mut pos, mut vel) = (projected.clone(), vec![[0.0; 3]; 22]);
        t.start(&placed);
        t.apply(&body, &mut pos, &mut vel, true);
        assert!(largest_strain(&t, &pos) <= TETHER_FOLLOW_STRETCH + 1e-4, "{}", largest_strain(&t, &pos));
        assert_eq!(pos[5], projected[5], "the vertex the projection moved most stays");
        assert!(t.moved() >= 2 && t.moved() < 22, "{}", t.moved());
        for (i, x) in pos.iter().enumerate() {
            assert!(dist(*x, body[i]) <= t.length[i] * (1.0 + 1e-5), "vertex {i} beyond its length");
            assert!((0..3).all(|k| (vel[i][k] - (x[k] - projected[i][k])).abs() < 1e-6), "velocity takes the move");
        }
        // A step whose projection moved nothing leaves the same stretch: the step's own.
        let (mut again, mut vel) = (projected.clone(), vec![[0.0; 3]; 22]);
        t.apply(&body, &mut again, &mut vel, false);
        assert_eq!((again, t.moved()), (projected, 0));
    }

    /// A sim's scene: a network that outputs nothing (its bytes), a 5 x 5 cloth 20 cm wide 1 cm
    /// above the top of an ellipsoid body, the body's vertices and mesh.
    fn cloth_over_a_body() -> (crate::model::ModelBytes, Garment, Vec<[f32; 3]>, crate::body::BodyMesh) {
        let (rest, faces) = grid(5, 5, 0.2, 0.2, 0.31);
        let garment = Garment::new(crate::mesh::GarmentDesc::new(&rest, &faces)).unwrap();
        let (body, body_faces) = crate::body::shapes::ellipsoid(32, 48, [0.25, 0.3, 0.25], [0.0; 3]);
        let mesh = crate::body::BodyMesh::new(body.len(), &body_faces).unwrap();
        (crate::sim::coasting_model_bytes(7), garment, body, mesh)
    }

    /// On a sim: a cloth whose network outputs nothing, over a body that drops 5 cm a frame, stays
    /// where it was without tethers and is held within its lengths with them; the step reports
    /// the pull, and a teleport forgets it. Tethers need a body.
    #[test]
    fn tethers_hold_a_cloth_on_a_body_that_drops_away() {
        use crate::body::rigid::RigidMotion;
        use crate::sim::{BodyDesc, Sim, SimConfig, StepEffects};

        let (bytes, garment, body, mesh) = cloth_over_a_body();
        let model = bytes.model().unwrap();
        let desc = || Some(BodyDesc { mesh: &mesh, positions: &body });
        let base = SimConfig { startup: false, ..SimConfig::network() };
        let mut free = Sim::new(&model, &garment, desc(), base).unwrap();
        let mut held = Sim::new(&model, &garment, desc(), base.with_tether(Some(0.02))).unwrap();
        assert_eq!(held.tethered_vertices(), 0, "tied at the first step");
        assert_eq!((free.tethered_vertices(), free.last_tethered()), (0, 0));
        let mut now = body.clone();
        for frame in 1..=10 {
            now = body.iter().map(|q| [q[0], q[1] - 0.05 * frame as f32, q[2]]).collect();
            free.step(&now).unwrap();
            held.step(&now).unwrap();
            // The pulls give the cloth the body's speed within a few frames; the first must pull.
            if frame == 1 {
                assert_eq!(held.tethered_vertices(), 25);
                assert!(held.last_effects().tethered && held.last_tethered() > 0);
            }
            assert!(!free.last_effects().tethered);
            let t = held.body.as_ref().unwrap().tethers.as_ref().unwrap();
            for (i, x) in held.positions().iter().enumerate() {
                let anchor = now[t.anchor[i] as usize];
                assert!(dist(*x, anchor) <= t.length[i] * (1.0 + 1e-5), "frame {frame} vertex {i}");
            }
        }
        // Without tethers the cloth stays about where it was (the random normalisers' mean output
        // moves it by millimetres), half a metre above the body's top.
        assert!(free.positions().iter().all(|x| (x[1] - 0.31).abs() < 0.02));
        assert!(held.positions().iter().all(|x| x[1] < 0.31 - 0.4));
        let motion = RigidMotion { rotation: glam::Quat::IDENTITY, translation: glam::Vec3::ZERO };
        held.teleport(&motion, &now).unwrap();
        assert_eq!(held.last_tethered(), 0);
        assert_eq!(held.last_effects(), StepEffects { teleported: true, ..StepEffects::default() });
        assert_eq!(held.tethered_vertices(), 25, "a teleport keeps the ties");
        let state = held.state().clone();
        held.set_state(&state).unwrap();
        assert_eq!(held.tethered_vertices(), 0, "a new placement ties again at the next step");
        let no_body = Sim::new(&model, &garment, None, base.with_tether(Some(0.02)));
        assert!(matches!(no_body, Err(Error::UnsupportedEffect { .. })));
    }

    /// With collision projection on as well, the tethers act last: a projection margin wider
    /// than the slack pushes the cloth out past its lengths, and every vertex is back within its
    /// length when the step ends.
    #[test]
    fn tethers_act_after_the_projection() {
        use crate::sim::{BodyDesc, Sim, SimConfig};

        // Tied with no slack 1 cm above the body; the projection keeps 3 cm.
        let (bytes, garment, body, mesh) = cloth_over_a_body();
        let model = bytes.model().unwrap();
        let cfg =
            SimConfig { startup: false, ..SimConfig::network() }.with_tether(Some(0.0)).with_projection(Some(0.03));
        let mut sim = Sim::new(&model, &garment, Some(BodyDesc { mesh: &mesh, positions: &body }), cfg).unwrap();
        let mut both = 0;
        for frame in 1..=5 {
            sim.step(&body).unwrap();
            both += usize::from(sim.last_projected() > 0 && sim.last_tethered() > 0);
            let t = sim.body.as_ref().unwrap().tethers.as_ref().unwrap();
            for (i, x) in sim.positions().iter().enumerate() {
                let anchor = body[t.anchor[i] as usize];
                assert!(dist(*x, anchor) <= t.length[i] * (1.0 + 1e-5), "frame {frame} vertex {i}");
            }
        }
        assert!(both > 0, "the projection pushed past a length and the tethers pulled back");
    }

    /// On a sim with both effects: a cloth placed with one edge at its middle stretched by 70 %
    /// is pushed out by the projection, and the cloth follows the push, though no tether pulls
    /// (half a metre of slack); with the projection alone the edge stays stretched.
    #[test]
    fn with_the_projection_the_cloth_follows_its_moves() {
        use crate::sim::{BodyDesc, Sim, SimConfig};

        let (bytes, garment, body, mesh) = cloth_over_a_body();
        let model = bytes.model().unwrap();
        let rest = garment.rest().to_vec();
        let strain = |pos: &[[f32; 3]], [i, j]: [u32; 2]| {
            let (i, j) = (i as usize, j as usize);
            dist(pos[i], pos[j]) / dist(rest[i], rest[j]) - 1.0
        };
        let projecting = SimConfig { startup: false, ..SimConfig::network() }.with_projection(Some(0.03));
        let mut strained = 0.0f32;
        for tether in [None, Some(0.5)] {
            let desc = Some(BodyDesc { mesh: &mesh, positions: &body });
            let mut sim = Sim::new(&model, &garment, desc, projecting.with_tether(tether)).unwrap();
            // Vertex 13, beside the middle one (12) 5 cm along x, placed 8.5 cm from it.
            let mut state = sim.state().clone();
            state.pos[13][0] = 0.085;
            assert!((strain(&state.pos, [12, 13]) - 0.7).abs() < 1e-4);
            sim.set_state(&state).unwrap();
            sim.step(&body).unwrap();
            assert!(sim.last_projected() > 0);
            let pos = sim.positions();
            match tether {
                None => strained = strain(pos, [12, 13]),
                Some(_) => {
                    assert!(sim.last_tethered() > 0, "the follow moved the cloth");
                    let worst = garment.edges().iter().map(|&e| strain(pos, e)).fold(0.0f32, f32::max);
                    assert!(worst <= TETHER_FOLLOW_STRETCH + 1e-4, "{worst}");
                    let t = sim.body.as_ref().unwrap().tethers.as_ref().unwrap();
                    assert!((0..25).all(|i| dist(pos[i], body[t.anchor[i] as usize]) < t.length[i]));
                }
            }
        }
        assert!(strained > 0.6, "the projection alone leaves the edge stretched: {strained}");
    }

    #[test]
    fn tethers_refuse_bad_slack_and_sizes() {
        let body = [[0.0; 3]];
        let (g, faces) = grid(2, 2, 0.1, 0.1, 0.01);
        let cloth = garment(&g, &faces);
        for bad in [-0.01, f32::NAN, f32::INFINITY, MAX_TETHER_SLACK * 1.5] {
            assert!(matches!(Tethers::new(&cloth, 1, bad), Err(Error::OutOfRange { .. })), "{bad}");
        }
        let mut t = Tethers::new(&cloth, 1, 0.0).unwrap();
        assert!(matches!(t.tie(&g, &[false; 3], &body), Err(Error::SizeMismatch { .. })));
        assert!(matches!(t.tie(&g[..3], &[false; 4], &body), Err(Error::SizeMismatch { .. })));
        assert!(t.tie(&g, &[false; 4], &[[0.0; 3], [1.0; 3]]).is_err(), "a body larger than made for");
        assert!(!t.tied());
        t.tie(&g, &[false; 4], &body).unwrap();
        assert!(t.tied());
        t.untie();
        assert!(!t.tied());
    }
}
