//! The body's motion over one frame and what it asks of the step: a pass in the speed limit's
//! frame of reference, a teleport instead of a step, or sleep.

use super::SimState;
use crate::body::rigid::{best_rigid_motion, RigidMotion};
use crate::math::norm3;

/// What a step does with the body's motion over the coming frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum FrameMotion {
    /// Step the garment, in the speed limit's frame of reference, which moves by `carry` metres
    /// over the frame (zero under the limit).
    Step {
        /// The part of the body's mean motion beyond the speed limit, m.
        carry: [f32; 3],
    },
    /// The body jumps: carry the garment by the body's best-fit rigid motion instead of
    /// stepping it through the jump.
    Jump(RigidMotion),
}

/// The step that the body's motion from `now` to `next` (m, the same body) asks for, with the
/// teleport threshold `teleport` (m) and the speed limit `speed_limit` (m/frame), each `None`
/// when off. With both off the body is not read at all.
pub(super) fn frame_motion(
    now: &[[f32; 3]],
    next: &[[f32; 3]],
    teleport: Option<f32>,
    speed_limit: Option<f32>,
) -> FrameMotion {
    if teleport.is_none() && speed_limit.is_none() {
        return FrameMotion::Step { carry: [0.0; 3] };
    }
    let moved = body_motion(now, next);
    let carry = speed_limit.map_or([0.0; 3], |l| excess_motion(moved.mean, l));
    match teleport {
        Some(limit) if jumps(now, next, &moved, carry, limit) => FrameMotion::Jump(best_rigid_motion(now, next)),
        _ => FrameMotion::Step { carry },
    }
}

/// The body's motion over one frame.
struct BodyMotion {
    /// Mean displacement of its vertices, m.
    mean: [f32; 3],
    /// Largest squared displacement of one vertex, m².
    largest2: f32,
}

/// The motion of the body's vertices from `now` to `next` (m), in one pass.
fn body_motion(now: &[[f32; 3]], next: &[[f32; 3]]) -> BodyMotion {
    let mut sum = [0.0f64; 3];
    let mut largest2 = 0.0f32;
    for (a, b) in now.iter().zip(next) {
        let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        for k in 0..3 {
            sum[k] += d[k] as f64;
        }
        largest2 = largest2.max(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    }
    let n = now.len().max(1) as f64;
    BodyMotion { mean: sum.map(|v| (v / n) as f32), largest2 }
}

/// The part of the displacement `d` beyond `limit` metres (zero when it is shorter), m.
fn excess_motion(d: [f32; 3], limit: f32) -> [f32; 3] {
    let len = norm3(d);
    if len.is_nan() || len <= limit {
        return [0.0; 3];
    }
    let s = 1.0 - limit / len;
    d.map(|v| v * s)
}

/// Whether the body jumps from `now` to `next` (m): as a whole, or some vertex beyond what the
/// speed limit carries (`carry`, m), moves farther than `limit` m. Fast motion that the limit
/// carries is no jump; only a carried step needs a second pass over the body.
fn jumps(now: &[[f32; 3]], next: &[[f32; 3]], moved: &BodyMotion, carry: [f32; 3], limit: f32) -> bool {
    let l2 = limit * limit;
    norm3(moved.mean) > limit
        || if carry == [0.0; 3] {
            moved.largest2 > l2
        } else {
            now.iter().zip(next).any(|(a, b)| {
                let d = [b[0] - a[0] - carry[0], b[1] - a[1] - carry[1], b[2] - a[2] - carry[2]];
                d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > l2
            })
        }
}

/// Whether body and garment are at rest: no body vertex moved farther than `threshold` m over
/// the last frame or moves farther over the next (to `body_next`; `None` without a body), and
/// no garment vertex is faster than `threshold` m/frame.
pub(super) fn at_rest(state: &SimState, body_next: Option<&[[f32; 3]]>, threshold: f32) -> bool {
    let t2 = threshold * threshold;
    let d2 = |a: [f32; 3], b: [f32; 3]| (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum::<f32>();
    let body_still = match body_next {
        None => true,
        Some(next) => {
            state.body_pos.iter().zip(next).all(|(a, b)| d2(*a, *b) <= t2)
                && state.body_prev.iter().zip(&state.body_pos).all(|(a, b)| d2(*a, *b) <= t2)
        }
    };
    body_still && state.velocity.iter().all(|v| d2(*v, [0.0; 3]) <= t2)
}

#[cfg(test)]
mod tests {
    use super::{excess_motion, frame_motion, FrameMotion};

    /// Under the limit nothing is carried; above it, exactly the excess, along the motion.
    #[test]
    fn the_speed_limit_carries_the_excess_of_the_mean_motion() {
        assert_eq!(excess_motion([0.1, 0.0, 0.0], 0.12), [0.0; 3]);
        assert_eq!(excess_motion([f32::NAN, 0.0, 0.0], 0.12), [0.0; 3]);
        let c = excess_motion([0.0, 0.0, 0.3], 0.12);
        assert!(c[0] == 0.0 && c[1] == 0.0 && (c[2] - 0.18).abs() < 1e-6, "{c:?}");
    }

    /// The body jumps when its mean motion, or one vertex's motion beyond the carry, passes the
    /// threshold; below it, a step carries the excess over the speed limit.
    #[test]
    fn a_jump_is_motion_beyond_the_threshold_that_the_limit_does_not_carry() {
        let now = [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let by = |d: [f32; 3]| now.map(|p| [p[0] + d[0], p[1] + d[1], p[2] + d[2]]);
        let step = |next: &[[f32; 3]], limit| frame_motion(&now, next, Some(0.45), limit);
        assert!(matches!(step(&by([0.3, 0.0, 0.0]), None), FrameMotion::Step { carry } if carry == [0.0; 3]));
        assert!(matches!(step(&by([0.5, 0.0, 0.0]), Some(0.12)), FrameMotion::Jump(_)));
        let FrameMotion::Step { carry } = step(&by([0.4, 0.0, 0.0]), Some(0.12)) else { panic!("no step") };
        assert!((carry[0] - 0.28).abs() < 1e-6 && carry[1] == 0.0 && carry[2] == 0.0, "{carry:?}");
        let mut one = now;
        one[2][1] += 0.6;
        assert!(matches!(step(&one, Some(0.12)), FrameMotion::Jump(_)));
        assert_eq!(frame_motion(&now, &by([9.0; 3]), None, None), FrameMotion::Step { carry: [0.0; 3] });
    }
}
