//! The off-body metric: how much of a garment has left the body. Penetration and the objective
//! gap look best when the garment is gone (nothing left to collide, nothing to stretch), so a
//! rollout is judged by this first: a garment that has left the body is a failure whatever its
//! other figures say.
//!
//! * **Worn vertices**: those within [`WORN_DISTANCE`] of the body surface in the initial state
//!   (frame 0): the part of the garment that is meant to sit on the body (a loose hem that hangs
//!   free from the start is not counted).
//! * **Off the body** at a frame: the percentage of worn vertices farther than
//!   [`OFF_DISTANCE`] from the body surface at that frame.
//! * **Drift** (garments with pins): the largest distance of any vertex from its skinned position
//!   (the animation's pin targets, which for a [`Scene`](crate::scene::Scene) are the whole
//!   garment skinned with the body): trousers whose legs slide off show here even while the waist
//!   holds.
//! * **Shift** (animations that carry the whole garment with the body,
//!   [`Animation::skins_garment`]): the distance between the centroid of the worn vertices and
//!   the centroid of their skinned positions: a top that rides up to the chest, or slides round
//!   the body, shows here while every vertex stays within [`OFF_DISTANCE`] of the body.
//!
//! A rollout has **lost** the garment ([`LossWatch`]) at the first frame where either holds:
//!
//! * **off the body** ([`OffBodyFrame::off`]): [`LOST_PERCENT`] or more of the worn vertices
//!   are off the body;
//! * **ridden up**: the shift was [`RIDE_UP_SHIFT`] or more on at least [`RIDE_UP_FRAMES`] of
//!   the last [`RIDE_UP_WINDOW`] frames (this one included). A top ridden up to the chest stays
//!   within 10 cm of the body but keeps that shift; a skirt flaring up on a jump's landing or
//!   trailing a sudden start, or a dress flying up on a jump, shifts as much for a few frames
//!   and comes back. The window tells them apart: the converged implicit step's loose dress on
//!   held-out jumps is shifted 10 cm or more on at most 13 of any 30 frames, a t-shirt ridden
//!   up by a network on a spin or a hop on 20 of 30 within a second of riding up.
//!   The direction does not count: a skirt stretched down the legs by too few solver iterations
//!   is lost the same way.
//!
//! Distances to the body surface are exact over the faces around the nearest body vertex (the
//! surface point nearest a garment vertex lies on one of them unless the body is coarser than
//! the distance measured; any error is below one body edge and never counts a worn vertex as off
//! by more than that).

use super::Animation;
use crate::body::geometry::point_triangle_distance;
use crate::body::{Nearest, PointGrid};
use crate::error::Result;
use alloc::vec;
use alloc::vec::Vec;
use glam::Vec3;

/// Largest distance to the body surface at frame 0 of a worn vertex, m.
pub const WORN_DISTANCE: f32 = 0.02;

/// Distance to the body surface beyond which a worn vertex is off the body, m.
pub const OFF_DISTANCE: f32 = 0.10;

/// The percentage of worn vertices off the body at or above which a frame has lost the garment
/// (the acceptance bound of the generalisation work: under 5 % at every frame).
pub const LOST_PERCENT: f64 = 5.0;

/// Shift (m) at or above which a frame counts towards a ride-up ([`LossWatch`]).
pub const RIDE_UP_SHIFT: f64 = 0.10;

/// Frames over which ride-up frames are counted (one second at 30 frames per second).
pub const RIDE_UP_WINDOW: usize = 30;

/// Frames of the last [`RIDE_UP_WINDOW`] with a shift of [`RIDE_UP_SHIFT`] or more at which the
/// garment has ridden up.
pub const RIDE_UP_FRAMES: usize = 20;

/// The figures of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OffBodyFrame {
    /// Percentage (0-100) of worn vertices farther than [`OFF_DISTANCE`] from the body surface.
    pub off_percent: f64,
    /// Largest distance of a vertex from its skinned position, m (garments with pins only).
    pub max_drift: Option<f64>,
    /// Distance between the centroid of the worn vertices and that of their skinned positions,
    /// m (`None` when the animation does not skin the whole garment,
    /// [`Animation::skins_garment`]).
    pub shift: Option<f64>,
}

/// The rule of [`LossWatch`] in words, for reports: a garment is on the body when this holds.
pub fn kept_rule() -> alloc::string::String {
    alloc::format!(
        "under {LOST_PERCENT} % of its worn vertices over {:.0} cm from the body at every frame, and their \
         centroid {:.0} cm or more from where the skinning carries it on fewer than {RIDE_UP_FRAMES} of any \
         {RIDE_UP_WINDOW} frames",
        100.0 * OFF_DISTANCE,
        100.0 * RIDE_UP_SHIFT
    )
}

impl OffBodyFrame {
    /// Whether the garment is off the body at this frame: [`LOST_PERCENT`] or more of its worn
    /// vertices over [`OFF_DISTANCE`] from it.
    pub fn off(&self) -> bool {
        self.off_percent >= LOST_PERCENT
    }

    /// Whether this frame counts towards a ride-up: shift of [`RIDE_UP_SHIFT`] or more.
    pub fn shifted(&self) -> bool {
        self.shift.is_some_and(|d| d >= RIDE_UP_SHIFT)
    }
}

/// How a rollout lost its garment.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Loss {
    /// [`LOST_PERCENT`] or more of the worn vertices off the body.
    OffBody,
    /// Shifted [`RIDE_UP_SHIFT`] or more on [`RIDE_UP_FRAMES`] of the last [`RIDE_UP_WINDOW`]
    /// frames.
    RiddenUp,
}

impl Loss {
    /// The cause in words: `off the body` or `ridden up`.
    pub fn describe(self) -> &'static str {
        match self {
            Loss::OffBody => "off the body",
            Loss::RiddenUp => "ridden up",
        }
    }
}

/// The verdict over a rollout, fed its [`OffBodyFrame`]s one consecutive frame at a time (no
/// allocation: the window is a bit set).
#[derive(Clone, Copy, Debug, Default)]
pub struct LossWatch {
    /// Bit `i`: the frame `i` frames back was [`OffBodyFrame::shifted`].
    shifted: u32,
}

const _: () = assert!(RIDE_UP_WINDOW <= 32 && RIDE_UP_FRAMES <= RIDE_UP_WINDOW);

impl LossWatch {
    /// Takes the next frame; `Some` when the garment is lost at it (the rule of the module
    /// docs). Off the body is reported first when both hold.
    pub fn observe(&mut self, frame: &OffBodyFrame) -> Option<Loss> {
        let window = (1u64 << RIDE_UP_WINDOW) - 1;
        self.shifted = ((u64::from(self.shifted) << 1 | u64::from(frame.shifted())) & window) as u32;
        if frame.off() {
            Some(Loss::OffBody)
        } else if self.shifted.count_ones() as usize >= RIDE_UP_FRAMES {
            Some(Loss::RiddenUp)
        } else {
            None
        }
    }

    /// The first loss over `frames` (consecutive, in order): its index and cause.
    pub fn first<'a>(frames: impl IntoIterator<Item = &'a OffBodyFrame>) -> Option<(usize, Loss)> {
        let mut watch = LossWatch::default();
        frames.into_iter().enumerate().find_map(|(i, f)| Some((i, watch.observe(f)?)))
    }
}

/// Measures [`OffBodyFrame`]s of one garment on one animation (buffers sized once).
pub struct OffBody {
    /// Indices of the worn vertices.
    worn: Vec<u32>,
    /// Whether to measure drift (the garment has pins).
    drift: bool,
    /// Whether to measure shift (the animation skins the whole garment).
    shift: bool,
    faces: Vec<[u32; 3]>,
    /// Body vertex to incident faces (CSR).
    ring_start: Vec<u32>,
    ring: Vec<u32>,
    grid: PointGrid,
    queries: Vec<[f32; 3]>,
    near: Vec<Nearest>,
    skinned: Vec<[f32; 3]>,
}

impl OffBody {
    /// The metric for `anim`'s garment, its worn vertices taken from
    /// [`Animation::initial_garment`] against body frame 0; `None` without a body.
    ///
    /// # Errors
    /// Errors of the animation and of the body queries.
    pub fn new(anim: &dyn Animation) -> Result<Option<OffBody>> {
        let Some(mesh) = anim.body_mesh() else { return Ok(None) };
        let nv = mesh.n_vertices();
        let faces = mesh.faces().to_vec();
        let mut count = vec![0u32; nv + 1];
        for f in &faces {
            for &v in f {
                count[v as usize + 1] += 1;
            }
        }
        for i in 0..nv {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut ring = vec![0u32; faces.len() * 3];
        for (fi, f) in faces.iter().enumerate() {
            for &v in f {
                ring[fill[v as usize] as usize] = fi as u32;
                fill[v as usize] += 1;
            }
        }
        let g = anim.garment();
        let n = g.n_vertices();
        let mut this = OffBody {
            worn: Vec::new(),
            drift: g.pinned().iter().any(|&p| p),
            shift: anim.skins_garment(),
            faces,
            ring_start: count,
            ring,
            grid: PointGrid::new(nv.max(1), (8 * nv).max(64))?,
            queries: vec![[0.0; 3]; n],
            near: vec![Nearest { index: 0, distance: 0.0 }; n],
            skinned: vec![[0.0; 3]; n],
        };
        let initial = anim.initial_garment()?;
        let mut dist = vec![0.0f32; n];
        this.surface_distances(anim.body_frame(0), &initial, &mut dist)?;
        this.worn = (0..n as u32).filter(|&i| dist[i as usize] <= WORN_DISTANCE).collect();
        Ok(Some(this))
    }

    /// Number of worn vertices.
    pub fn n_worn(&self) -> usize {
        self.worn.len()
    }

    /// Distance (m) of every point of `points` to the body surface at `body` positions.
    fn surface_distances(&mut self, body: &[[f32; 3]], points: &[[f32; 3]], out: &mut [f32]) -> Result<()> {
        self.grid.rebuild(body)?;
        let n = points.len();
        if self.queries.len() < n {
            self.queries.resize(n, [0.0; 3]);
            self.near.resize(n, Nearest { index: 0, distance: 0.0 });
        }
        self.queries[..n].copy_from_slice(points);
        self.grid.nearest(&self.queries[..n], &mut self.near[..n])?;
        for (i, o) in out.iter_mut().enumerate().take(n) {
            let p = Vec3::from(points[i]);
            let v = self.near[i].index as usize;
            let (a, b) = (self.ring_start[v] as usize, self.ring_start[v + 1] as usize);
            let mut best = self.near[i].distance;
            for &f in &self.ring[a..b] {
                let [x, y, z] = self.faces[f as usize].map(|k| Vec3::from(body[k as usize]));
                best = best.min(point_triangle_distance(p, x, y, z));
            }
            *o = best;
        }
        Ok(())
    }

    /// The figures of frame `t` with the garment at `garment` (m).
    ///
    /// # Errors
    /// Errors of the animation and of the body queries.
    pub fn measure(&mut self, anim: &dyn Animation, t: usize, garment: &[[f32; 3]]) -> Result<OffBodyFrame> {
        let worn: Vec<[f32; 3]> = self.worn.iter().map(|&i| garment[i as usize]).collect();
        let mut dist = vec![0.0f32; worn.len()];
        self.surface_distances(anim.body_frame(t), &worn, &mut dist)?;
        let off = dist.iter().filter(|&&d| d > OFF_DISTANCE).count();
        let off_percent = if worn.is_empty() { 0.0 } else { 100.0 * off as f64 / worn.len() as f64 };
        anim.pin_targets(t, &mut self.skinned)?;
        let centroid = |x: &[[f32; 3]]| {
            self.worn.iter().map(|&i| Vec3::from(x[i as usize]).as_dvec3()).sum::<glam::DVec3>()
                / self.worn.len().max(1) as f64
        };
        let shift = self.shift.then(|| (centroid(garment) - centroid(&self.skinned)).length());
        let max_drift = if self.drift {
            let d = garment
                .iter()
                .zip(&self.skinned)
                .map(|(a, b)| (Vec3::from(*a) - Vec3::from(*b)).length())
                .fold(0.0f32, f32::max);
            Some(d as f64)
        } else {
            None
        };
        Ok(OffBodyFrame { off_percent, max_drift, shift })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::procedural::Mannequin;
    use crate::scene::{procedural, GarmentKind, MotionKind};

    #[test]
    fn a_garment_in_place_is_on_and_one_moved_away_is_off() {
        let m = Mannequin::new();
        let s = procedural(&m, GarmentKind::Skirt, 400, MotionKind::Walk, 1.0).unwrap();
        let mut ob = OffBody::new(&s).unwrap().unwrap();
        assert!(ob.n_worn() > 50, "{} worn vertices", ob.n_worn());
        let x0 = s.initial_garment(0).unwrap();
        let on = ob.measure(&s, 0, &x0).unwrap();
        assert_eq!(on.off_percent, 0.0);
        // The skirt is pinned: at frame 0 it sits at its skinned pose.
        assert!(on.max_drift.unwrap() < 0.01, "{:?}", on.max_drift);
        assert!(on.shift.unwrap() < 0.01, "{:?}", on.shift);
        assert!(!on.off() && !on.shifted());
        // Ridden up 15 cm: still on the body, shifted 15 cm (a figure, not the verdict).
        let up: Vec<[f32; 3]> = x0.iter().map(|p| [p[0], p[1] + 0.15, p[2]]).collect();
        let ridden = ob.measure(&s, 0, &up).unwrap();
        assert!((ridden.shift.unwrap() - 0.15).abs() < 0.01, "{:?}", ridden.shift);
        assert!(!ridden.off() && ridden.shifted(), "{ridden:?}");
        // Without skinned targets for the whole garment (a playback of fixed targets) there is
        // no shift to measure.
        let mut fixed = crate::eval::Playback::record(&s, 2).unwrap();
        fixed.pin_targets.clear();
        let mut ob_fixed = OffBody::new(&fixed).unwrap().unwrap();
        let ridden = ob_fixed.measure(&fixed, 0, &up).unwrap();
        assert_eq!(ridden.shift, None);
        assert!(!ridden.off() && !ridden.shifted());
        // Half the worn vertices 30 cm out, away from the body's vertical axis: half off,
        // drift 30 cm.
        let mut moved = x0.clone();
        let half: Vec<u32> = ob.worn.iter().copied().step_by(2).collect();
        let body = s.body_frame(0);
        let axis = body.iter().map(|p| Vec3::from(*p)).sum::<Vec3>() / body.len() as f32;
        for &i in &half {
            let p = Vec3::from(moved[i as usize]);
            let out = Vec3::new(p.x - axis.x, 0.0, p.z - axis.z).normalize();
            moved[i as usize] = (p + 0.3 * out).to_array();
        }
        let f = ob.measure(&s, 0, &moved).unwrap();
        let expected = 100.0 * half.len() as f64 / ob.n_worn() as f64;
        assert!((f.off_percent - expected).abs() < 5.0, "{} against {expected}", f.off_percent);
        assert!((f.max_drift.unwrap() - 0.3).abs() < 0.02);
        // The whole garment dropped 1 m: all off.
        let dropped: Vec<[f32; 3]> = x0.iter().map(|p| [p[0], p[1] - 3.0, p[2]]).collect();
        assert_eq!(ob.measure(&s, 0, &dropped).unwrap().off_percent, 100.0);
    }

    /// A frame with the given percentage off and shift (cm).
    fn frame(off_percent: f64, shift_cm: f64) -> OffBodyFrame {
        OffBodyFrame { off_percent, max_drift: None, shift: Some(shift_cm / 100.0) }
    }

    #[test]
    fn a_ride_up_is_a_loss_only_when_it_stays() {
        // A flare: 12 cm for 13 frames of every 30, over 300 frames: kept.
        let flare: Vec<OffBodyFrame> = (0..300).map(|t| frame(0.0, if t % 30 < 13 { 12.0 } else { 3.0 })).collect();
        assert_eq!(LossWatch::first(&flare), None);
        // 19 of 30 frames shifted, at the window's edges: still kept.
        let edge: Vec<OffBodyFrame> = (0..300).map(|t| frame(0.0, if t % 30 < 19 { 12.0 } else { 9.9 })).collect();
        assert_eq!(LossWatch::first(&edge), None);
        // Ridden up from frame 50 and staying: lost at the 20th shifted frame.
        let ride: Vec<OffBodyFrame> = (0..300).map(|t| frame(0.0, if t >= 50 { 12.0 } else { 1.0 })).collect();
        assert_eq!(LossWatch::first(&ride), Some((69, Loss::RiddenUp)));
        // Riding up with dips below 10 cm (a hop's cycle): lost once 20 of 30 are shifted.
        let hop: Vec<OffBodyFrame> = (0..300).map(|t| frame(0.0, if t % 10 < 7 { 12.0 } else { 8.0 })).collect();
        // (7 + 7 + 6 shifted frames by frame 25).
        assert_eq!(LossWatch::first(&hop), Some((25, Loss::RiddenUp)));
        // Off the body at one frame is lost at that frame, whatever the shift.
        let mut off = flare.clone();
        off[7].off_percent = LOST_PERCENT;
        assert_eq!(LossWatch::first(&off), Some((7, Loss::OffBody)));
        // No shift measured (held targets): only the off-body rule applies.
        let none: Vec<OffBodyFrame> =
            (0..100).map(|_| OffBodyFrame { off_percent: 4.9, ..Default::default() }).collect();
        assert_eq!(LossWatch::first(&none), None);
    }

    #[test]
    fn surface_distance_is_exact_over_the_faces_near_a_vertex() {
        let m = Mannequin::new();
        let s = procedural(&m, GarmentKind::Skirt, 400, MotionKind::Walk, 1.0).unwrap();
        let mut ob = OffBody::new(&s).unwrap().unwrap();
        let body = s.body_frame(0);
        // Points 5 cm out along face normals from face centroids are 5 cm from the surface
        // (the body is smooth at that scale); the brute force agrees with the metric.
        let faces = s.body.faces();
        let pts: Vec<[f32; 3]> = (0..faces.len())
            .step_by(97)
            .map(|fi| {
                let [a, b, c] = faces[fi].map(|k| Vec3::from(body[k as usize]));
                let n = (b - a).cross(c - a).normalize();
                ((a + b + c) / 3.0 + 0.05 * n).to_array()
            })
            .collect();
        let mut d = vec![0.0; pts.len()];
        ob.surface_distances(body, &pts, &mut d).unwrap();
        for (p, &got) in pts.iter().zip(&d) {
            let brute = faces
                .iter()
                .map(|f| {
                    let [a, b, c] = f.map(|k| Vec3::from(body[k as usize]));
                    point_triangle_distance(Vec3::from(*p), a, b, c)
                })
                .fold(f32::MAX, f32::min);
            assert!(got >= brute - 1e-6 && got - brute < 0.005, "metric {got}, brute force {brute}");
        }
    }
}
