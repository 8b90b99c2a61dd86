//! Animations: the channels that move a node on a joint's path to the root, read by the `gltf`
//! crate's channel reader after [`accessor::check`], and sampled at any time (`STEP`, `LINEAR`
//! with shortest-arc slerp for rotations, `CUBICSPLINE` Hermite splines).

use super::skeleton::Local;
use super::{accessor, buffers, err};
use crate::error::Result;
use crate::limits;
use glam::{DQuat, DVec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::animation::util::ReadOutputs;
use gltf::animation::{Interpolation, Property};
use std::borrow::Cow;
use std::format;
use std::vec::Vec;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Target {
    Translation,
    Rotation,
    Scale,
}

/// One animated property of one node.
#[derive(Clone, Debug)]
pub(super) struct Channel {
    /// The animated node.
    pub(super) node: usize,
    target: Target,
    interpolation: Interpolation,
    /// Key times, seconds, strictly increasing.
    times: Vec<f32>,
    /// Values (`w = 0` for a translation or a scale): one per key, or (in-tangent, value,
    /// out-tangent) per key for `CUBICSPLINE`.
    values: Vec<[f32; 4]>,
}

/// One animation of the file.
#[derive(Clone, Debug)]
pub(super) struct Clip {
    /// Earliest and latest key of all its channels, seconds.
    pub(super) start: f64,
    pub(super) end: f64,
    /// The channels on the joints' paths to the root.
    pub(super) channels: Vec<Channel>,
}

/// Reads an animation (named `name` in errors): every channel's keys count for the time range,
/// but only the translation, rotation and scale channels of nodes `in_chain` are kept (`rest`:
/// the nodes' stored transforms, which must not be matrices there).
pub(super) fn read(
    buffers: &[Cow<'_, [u8]>],
    anim: &gltf::Animation,
    name: &str,
    in_chain: &[bool],
    rest: &[Local],
) -> Result<Clip> {
    let (mut start, mut end) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut channels = Vec::new();
    for ch in anim.channels() {
        let at = format!("animation '{name}' channel {}", ch.index());
        let sampler = ch.sampler();
        let reader = ch.reader(buffers::lookup(buffers));
        let input = sampler.input();
        let what = accessor::label(&format!("{at} input"), &input);
        let n =
            accessor::check(buffers, &input, &what, Dimensions::Scalar, &[DataType::F32], limits::MAX_MOTION_SAMPLES)?;
        let times = accessor::collect(n, &what, || reader.read_inputs())?;
        accessor::finite(&times, 1, &what)?;
        if times.is_empty() {
            return Err(err(format!("{at}: no keys")));
        }
        if let Some(k) = times.windows(2).position(|w| w[1] <= w[0]) {
            return Err(err(format!("{at}: key times are not strictly increasing (key {})", k + 1)));
        }
        start = start.min(times[0] as f64);
        end = end.max(times[times.len() - 1] as f64);
        let node = ch.target().node().index();
        let target = match ch.target().property() {
            Property::Translation => Target::Translation,
            Property::Rotation => Target::Rotation,
            Property::Scale => Target::Scale,
            Property::MorphTargetWeights => continue,
        };
        if !in_chain[node] {
            continue;
        }
        if matches!(rest[node], Local::Matrix(_)) {
            return Err(err(format!(
                "{at}: animates node {node}, whose transform is a matrix (glTF animates only translation, \
                 rotation and scale)"
            )));
        }
        let interpolation = sampler.interpolation();
        let (dims, types): (Dimensions, &[DataType]) = match target {
            Target::Rotation => {
                (Dimensions::Vec4, &[DataType::F32, DataType::I8, DataType::U8, DataType::I16, DataType::U16])
            }
            _ => (Dimensions::Vec3, &[DataType::F32]),
        };
        let output = sampler.output();
        let what = accessor::label(&format!("{at} output"), &output);
        let n = accessor::check(buffers, &output, &what, dims, types, limits::MAX_MOTION_SAMPLES)?;
        let values = accessor::collect(n, &what, || reader.read_outputs().map(|o| vec4s(o).into_iter()))?;
        accessor::finite(values.as_flattened(), 4, &what)?;
        let per_key = if interpolation == Interpolation::CubicSpline { 3 } else { 1 };
        if values.len() != times.len() * per_key {
            return Err(err(format!(
                "{at}: {} output values for {} keys ({per_key} per key with {interpolation:?})",
                values.len(),
                times.len()
            )));
        }
        let channel = Channel { node, target, interpolation, times, values };
        if target == Target::Rotation {
            if let Some(k) = (0..channel.times.len()).find(|&k| DQuat::from_array(channel.key(k)).length() < 1e-6) {
                return Err(err(format!("{at}: key {k} is not a rotation (zero quaternion)")));
            }
        }
        channels.push(channel);
    }
    if channels.is_empty() && !start.is_finite() {
        start = 0.0;
        end = 0.0;
    }
    Ok(Clip { start, end, channels })
}

/// A channel's output values as 4-vectors (`w = 0` for translations and scales).
fn vec4s(outputs: ReadOutputs<'_>) -> Vec<[f32; 4]> {
    match outputs {
        ReadOutputs::Translations(v) | ReadOutputs::Scales(v) => v.map(|[x, y, z]| [x, y, z, 0.0]).collect(),
        ReadOutputs::Rotations(r) => r.into_f32().collect(),
        ReadOutputs::MorphTargetWeights(_) => Vec::new(),
    }
}

impl Channel {
    /// Element `i` of the values.
    fn element(&self, i: usize) -> [f64; 4] {
        self.values[i].map(f64::from)
    }

    /// The value of key `k` (the middle element of a cubic key).
    fn key(&self, k: usize) -> [f64; 4] {
        self.element(if self.interpolation == Interpolation::CubicSpline { 3 * k + 1 } else { k })
    }

    /// The channel's value at `t` seconds.
    fn sample(&self, t: f64) -> [f64; 4] {
        let n = self.times.len();
        let after = self.times.partition_point(|&x| (x as f64) <= t);
        if after == 0 {
            return self.key(0);
        }
        if after == n {
            return self.key(n - 1);
        }
        let k = after - 1;
        let (t0, t1) = (self.times[k] as f64, self.times[k + 1] as f64);
        let dt = t1 - t0;
        let s = ((t - t0) / dt).clamp(0.0, 1.0);
        match self.interpolation {
            Interpolation::Step => self.key(k),
            Interpolation::Linear => {
                let (a, b) = (self.key(k), self.key(k + 1));
                if self.target == Target::Rotation {
                    let (qa, qb) = (DQuat::from_array(a).normalize(), DQuat::from_array(b).normalize());
                    qa.slerp(qb, s).to_array()
                } else {
                    let mut out = [0.0; 4];
                    for i in 0..3 {
                        out[i] = a[i] + (b[i] - a[i]) * s;
                    }
                    out
                }
            }
            Interpolation::CubicSpline => {
                let (v0, b0) = (self.element(3 * k + 1), self.element(3 * k + 2));
                let (a1, v1) = (self.element(3 * k + 3), self.element(3 * k + 4));
                let (s2, s3) = (s * s, s * s * s);
                let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
                let h10 = (s3 - 2.0 * s2 + s) * dt;
                let h01 = -2.0 * s3 + 3.0 * s2;
                let h11 = (s3 - s2) * dt;
                let mut out = [0.0; 4];
                for i in 0..4 {
                    out[i] = h00 * v0[i] + h10 * b0[i] + h01 * v1[i] + h11 * a1[i];
                }
                out
            }
        }
    }

    /// Sets the animated property of `local` (a TRS node) to its value at `t` seconds.
    pub(super) fn apply(&self, t: f64, local: &mut Local) {
        let v = self.sample(t);
        if let Local::Trs { t: tr, r, s } = local {
            match self.target {
                Target::Translation => *tr = DVec3::new(v[0], v[1], v[2]),
                Target::Scale => *s = DVec3::new(v[0], v[1], v[2]),
                Target::Rotation => {
                    let q = DQuat::from_array(v);
                    // A spline through opposite keys may pass near zero; keep the last rotation there.
                    if q.length_squared() > 1e-12 {
                        *r = q.normalize();
                    }
                }
            }
        }
    }
}
