//! Evaluation metrics (EVALUATION.md "Accuracy") and the scoring of a whole rollout.

use super::collision::plane_distances;
use super::{face_frames, CentroidQuery, Cloth, CollisionInput, FaceFrame, FrictionFrames, FrictionInput, Objective};
use super::{StepInputs, Terms};
use crate::body::{Nearest, PointGrid};
use crate::error::{Error, Result};
use crate::math::{norm3, sub3, Real};
use crate::mesh::Garment;
use alloc::vec;
use alloc::vec::Vec;

/// A vertex is penetrating when its distance to the plane of its nearest body face is below
/// this, m (the evaluation form's collision eps).
pub const PENETRATION_DEPTH: f64 = 1e-3;

/// The figures of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameScore {
    /// Every term of the objective (evaluation form unless another objective was given).
    pub terms: Terms<f64>,
    /// Their sum.
    pub total: f64,
    /// Percentage (0-100) of garment vertices closer than [`PENETRATION_DEPTH`] to (or behind)
    /// the plane of their nearest body face; 0 without a body.
    pub penetrating_percent: f64,
    /// Largest `|l / L - 1|` over the garment's edges (current / rest length).
    pub max_edge_strain: f64,
    /// Largest vertex speed `|x - pos| / dt`, m/s.
    pub max_speed: f64,
}

/// Per-frame figures of a rollout and their means.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RolloutScore {
    /// One entry per scored frame (frames 1..N of the rollout).
    pub frames: Vec<FrameScore>,
    /// The mean of every field over the frames.
    pub mean: FrameScore,
}

/// Largest `|l / L - 1|` over the edges at positions `x`.
pub fn max_edge_strain<T: Real>(cloth: &Cloth<T>, x: &[[T; 3]]) -> f64 {
    max_edge_strains(cloth, x, T::ZERO)[0]
}

/// Largest `|l / L - 1|` at positions `x`, in one pass: over every edge, and over the edges
/// whose rest length `L` is at least `min_rest` (m; 0 when there is none).
pub fn max_edge_strains<T: Real>(cloth: &Cloth<T>, x: &[[T; 3]], min_rest: T) -> [f64; 2] {
    let mut worst = [0.0f64; 2];
    for (e, &rest) in cloth.edges.iter().zip(&cloth.rest_len) {
        let l = norm3(sub3(x[e[1] as usize], x[e[0] as usize]));
        let strain = (l / rest - T::ONE).abs().to_f64();
        worst[0] = worst[0].max(strain);
        if rest >= min_rest {
            worst[1] = worst[1].max(strain);
        }
    }
    worst
}

/// A quarter of the median rest length of the cloth's edges (m; 0 without edges): the shortest
/// edge the evaluation's long-edge strain counts ([`max_edge_strains`]). Modelled meshes
/// have sliver edges (the MakeHuman t-shirt has 48 under a quarter of its median of 22 mm, 15
/// under 2.2 mm) that a move of a few millimetres strains many times over, and the largest
/// strain over every edge is often one of them.
pub fn quarter_median_edge_length<T: Real>(cloth: &Cloth<T>) -> T {
    let mut rest = cloth.rest_len.clone();
    rest.sort_unstable_by(|a, b| a.partial_cmp(b).unwrap_or(core::cmp::Ordering::Equal));
    rest.get(rest.len() / 2).map_or(T::ZERO, |&m| m * T::from_f64(0.25))
}

/// Scores a rollout with a caller-chosen nearest-centroid query: `garment[t]` and `body[t]` are the garment and body vertex positions (m) at
/// frame `t` (same count N ≥ 2, body optional: pass `body` empty for a scene without one), `dt`
/// in s. Frame `t ≥ 1` is scored as the step from `garment[t-1]` (velocity
/// `garment[t-1] - garment[t-2]`, zero at `t = 1`) to `garment[t]`, with the body at `t-1`
/// (current) and `t` (next). `objective` picks the terms (usually [`Objective::evaluation`]);
/// contact terms are dropped when there is no body. `make_query` builds a nearest-centroid
/// query over a set of face centroids (e.g. the body module's grid, or
/// [`super::BruteForceCentroids`]). Computed in f64.
///
/// # Errors
/// [`Error::Empty`] with fewer than two frames; [`Error::SizeMismatch`] when frame counts or
/// vertex counts disagree; errors of the terms.
pub fn score_rollout_with<Q: CentroidQuery>(
    garment: &Garment,
    objective: &Objective,
    garment_frames: &[Vec<[f32; 3]>],
    body_frames: &[Vec<[f32; 3]>],
    body_faces: &[[u32; 3]],
    dt: f64,
    mut make_query: impl FnMut(&[[f32; 3]]) -> Q,
) -> Result<RolloutScore> {
    let mut nearest = |centroids: &[[f32; 3]], points: &[[f32; 3]], out: &mut [u32]| -> Result<()> {
        make_query(centroids).nearest_into(points, out);
        Ok(())
    };
    score(garment, objective, garment_frames, body_frames, body_faces, dt, &mut nearest)
}

/// [`score_rollout_with`] using the body module's centroid grid ([`PointGrid`]) for the
/// nearest-face queries: the usual entry point.
///
/// # Errors
/// As [`score_rollout_with`]; [`Error::NonFinite`] for a NaN/Inf body or garment position.
pub fn score_rollout(
    garment: &Garment,
    objective: &Objective,
    garment_frames: &[Vec<[f32; 3]>],
    body_frames: &[Vec<[f32; 3]>],
    body_faces: &[[u32; 3]],
    dt: f64,
) -> Result<RolloutScore> {
    let nf = body_faces.len();
    let mut grid = PointGrid::new(nf.max(1), (8 * nf).max(64))?;
    let mut found = vec![Nearest { index: 0, distance: 0.0 }; garment.n_vertices()];
    let mut nearest = |centroids: &[[f32; 3]], points: &[[f32; 3]], out: &mut [u32]| -> Result<()> {
        grid.rebuild(centroids)?;
        grid.nearest(points, &mut found)?;
        for (o, f) in out.iter_mut().zip(&found) {
            *o = f.index;
        }
        Ok(())
    };
    score(garment, objective, garment_frames, body_frames, body_faces, dt, &mut nearest)
}

type NearestFn<'a> = dyn FnMut(&[[f32; 3]], &[[f32; 3]], &mut [u32]) -> Result<()> + 'a;

fn score(
    garment: &Garment,
    objective: &Objective,
    garment_frames: &[Vec<[f32; 3]>],
    body_frames: &[Vec<[f32; 3]>],
    body_faces: &[[u32; 3]],
    dt: f64,
    nearest: &mut NearestFn<'_>,
) -> Result<RolloutScore> {
    let nt = garment_frames.len();
    if nt < 2 {
        return Err(Error::Empty { what: "rollout (needs at least two frames)" });
    }
    let has_body = !body_frames.is_empty();
    if has_body && body_frames.len() != nt {
        return Err(Error::SizeMismatch { what: "body frames", expected: nt, got: body_frames.len() });
    }
    let cloth = Cloth::<f64>::new(garment);
    let n = cloth.n_vertices();
    for g in garment_frames {
        super::check_len("garment frame", g.len(), n)?;
    }
    let mut objective = *objective;
    if !has_body {
        objective.collision = None;
        objective.friction = None;
    }
    let nf = body_faces.len();
    let to64 = |v: &[[f32; 3]], out: &mut Vec<[f64; 3]>| {
        out.clear();
        out.extend(v.iter().map(|p| p.map(|c| c as f64)));
    };
    let (mut x, mut pos, mut prev) = (Vec::new(), Vec::new(), Vec::new());
    let mut vel = vec![[0.0f64; 3]; n];
    // Body faces at the frames t-2, t-1, t: centroids and normals (f64) plus f32 centroids for queries.
    let mut cent = [vec![[0.0f64; 3]; nf], vec![[0.0f64; 3]; nf], vec![[0.0f64; 3]; nf]];
    let mut norms = [vec![[0.0f64; 3]; nf], vec![[0.0f64; 3]; nf], vec![[0.0f64; 3]; nf]];
    let mut cent32 = vec![[0.0f32; 3]; nf];
    let (mut near_cur, mut near_a, mut near_b) = (vec![0u32; n], vec![0u32; n], vec![0u32; n]);
    let mut dist = vec![0.0f64; n];
    let mut frames = Vec::with_capacity(nt - 1);
    let f32s = |v: &[[f64; 3]]| -> Vec<[f32; 3]> { v.iter().map(|p| p.map(|c| c as f32)).collect() };
    for t in 1..nt {
        to64(&garment_frames[t], &mut x);
        to64(&garment_frames[t - 1], &mut pos);
        if t >= 2 {
            to64(&garment_frames[t - 2], &mut prev);
            for i in 0..n {
                vel[i] = sub3(pos[i], prev[i]);
            }
        }
        let mut inputs = StepInputs { pos: &pos, velocity: &vel, dt, collision: None, friction: None };
        let mut penetrating = 0.0;
        if has_body {
            let tp = t.saturating_sub(2);
            for (slot, frame) in [(0usize, tp), (1, t - 1), (2, t)] {
                let (c, nr) = (&mut cent[slot], &mut norms[slot]);
                face_frames(&body_frames[frame], body_faces, c, nr)?;
            }
            for (c32, c) in cent32.iter_mut().zip(&cent[1]) {
                *c32 = c.map(|v| v as f32);
            }
            nearest(&cent32, &garment_frames[t - 1], &mut near_cur)?;
            let next = FaceFrame { centroids: &cent[2], normals: &norms[2] };
            plane_distances(&x, &near_cur, next, &mut dist);
            let count = dist.iter().filter(|&&d| d < PENETRATION_DEPTH).count();
            penetrating = 100.0 * count as f64 / n as f64;
            inputs.collision = Some(CollisionInput { nearest: &near_cur, next });
            if let Some(fp) = &objective.friction {
                let (a, b) = match fp.frames {
                    FrictionFrames::CurrentNext => (1, 2),
                    FrictionFrames::PrevCurrent => (0, 1),
                };
                nearest(&f32s(&cent[a]), &garment_frames[t - 1], &mut near_a)?;
                nearest(&f32s(&cent[b]), &garment_frames[t], &mut near_b)?;
                inputs.friction = Some(FrictionInput {
                    frame_a: FaceFrame { centroids: &cent[a], normals: &norms[a] },
                    frame_b: FaceFrame { centroids: &cent[b], normals: &norms[b] },
                    nearest_a: &near_a,
                    nearest_b: &near_b,
                });
            }
        }
        let terms = objective.eval(&cloth, &inputs, &x, None)?;
        let max_speed = x.iter().zip(&pos).map(|(a, b)| norm3(sub3(*a, *b))).fold(0.0f64, f64::max) / dt;
        frames.push(FrameScore {
            terms,
            total: terms.total(),
            penetrating_percent: penetrating,
            max_edge_strain: max_edge_strain(&cloth, &x),
            max_speed,
        });
    }
    let mean = mean_score(&frames);
    Ok(RolloutScore { frames, mean })
}

fn mean_score(frames: &[FrameScore]) -> FrameScore {
    let k = frames.len().max(1) as f64;
    let mut m = FrameScore::default();
    for f in frames {
        m.terms.stretching += f.terms.stretching / k;
        m.terms.bending += f.terms.bending / k;
        m.terms.inertia += f.terms.inertia / k;
        m.terms.gravity += f.terms.gravity / k;
        m.terms.collision += f.terms.collision / k;
        m.terms.friction += f.terms.friction / k;
        m.total += f.total / k;
        m.penetrating_percent += f.penetrating_percent / k;
        m.max_edge_strain += f.max_edge_strain / k;
        m.max_speed += f.max_speed / k;
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Garment, GarmentDesc};

    /// A strip of four 10 cm squares with a sliver triangle on its end, one edge of it 1 mm
    /// long: shorter than a quarter of the median edge, a 4 mm move strains it four times over,
    /// and the long-edge strain leaves it out.
    #[test]
    fn the_long_edge_strain_leaves_out_sliver_edges() {
        let mut rest: Vec<[f32; 3]> =
            (0..5).flat_map(|i| [[0.1 * i as f32, 0.0, 0.0], [0.1 * i as f32, 0.1, 0.0]]).collect();
        rest.push([0.401, 0.0, 0.0]);
        let mut faces: Vec<[u32; 3]> =
            (0..4u32).flat_map(|i| [[2 * i, 2 * i + 2, 2 * i + 3], [2 * i, 2 * i + 3, 2 * i + 1]]).collect();
        faces.push([8, 10, 9]);
        let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
        let cloth = Cloth::<f64>::new(&g);
        let bound = quarter_median_edge_length(&cloth);
        assert!((bound - 0.025).abs() < 1e-9, "{bound}");

        let mut x: Vec<[f64; 3]> = rest.iter().map(|p| p.map(f64::from)).collect();
        x[1][1] += 0.011; // the square's edge 0-1 by 11 %
        x[10][0] += 0.004; // the sliver's 1 mm edge 8-10
        let all = max_edge_strain(&cloth, &x);
        assert!(all > 3.0, "{all}");
        let [also_all, long] = max_edge_strains(&cloth, &x, bound);
        assert_eq!(also_all, all);
        assert!((long - 0.11).abs() < 1e-6, "{long}");
        assert_eq!(max_edge_strains(&cloth, &x, 0.0), [all, all]);
    }
}
