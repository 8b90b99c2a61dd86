//! Bring your own garment: a mesh of the user's (any unit, y or z up) made a [`Garment`] with a
//! material and pins, for a rigged body (the pins are then skinned with the body, as in
//! [`super::Scene`]) or a body given frame by frame (the pins ride on the nearest body face,
//! [`FaceAttachment`]).
//!
//! The garment is given around the body as the body stands in its reference shape: the rest
//! (bind) pose of a rigged body, the first frame of a body sequence.

use crate::body::geometry::point_triangle_distance;
use crate::body::{BodyFrame, BodyMesh, Nearest};
use crate::error::{Error, Result};
use crate::math::{add3, cross3, dot3, norm3, scale3, sub3};
use crate::mesh::{Garment, GarmentDesc, Material};
use crate::rig::fit::pinned_flags;
use alloc::vec;
use alloc::vec::Vec;
use glam::Vec3;

/// Which axis of the garment's file points up (the crate's frame is y up).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum UpAxis {
    /// y up (OBJ from MakeHuman, Maya, most engines): taken as it is.
    #[default]
    Y,
    /// z up (Blender's and 3ds Max's own frame, when exported without conversion): `(x, y, z)`
    /// becomes `(x, z, -y)`, so the file's front (-y) faces +z.
    Z,
}

impl UpAxis {
    /// `y` or `z`.
    pub fn parse(name: &str) -> Option<UpAxis> {
        match name {
            "y" | "Y" => Some(UpAxis::Y),
            "z" | "Z" => Some(UpAxis::Z),
            _ => None,
        }
    }

    /// `p` of the file's frame in the crate's (y up).
    pub fn to_y_up(self, p: [f32; 3]) -> [f32; 3] {
        match self {
            UpAxis::Y => p,
            UpAxis::Z => [p[0], p[2], -p[1]],
        }
    }
}

/// Which garment vertices follow the body instead of the physics.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Pins {
    /// None: the garment hangs on the body (tops, dresses).
    None,
    /// [`auto_pins`]: the waistband of a garment that has nothing to hang from.
    #[default]
    Auto,
    /// These vertices (0-based indices into the garment's positions).
    Vertices(Vec<u32>),
}

/// How to make a garment of a user's mesh.
///
/// Built from [`Default`] and the `with_` methods (new fields may come, so it has no struct
/// literal outside this crate).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct GarmentOptions {
    /// Metres per unit of the file (0.01 for centimetres).
    pub scale: f32,
    /// The file's up axis.
    pub up: UpAxis,
    /// Added after turning and scaling, in the body's frame (m).
    pub offset: [f32; 3],
    /// The pinned vertices.
    pub pins: Pins,
    /// Every vertex's material (`None`: [`Material::default`]).
    pub material: Option<Material>,
}

impl Default for GarmentOptions {
    fn default() -> Self {
        GarmentOptions { scale: 1.0, up: UpAxis::Y, offset: [0.0; 3], pins: Pins::Auto, material: None }
    }
}

impl GarmentOptions {
    with_fields! {
        /// Sets [`scale`](Self::scale): metres per unit of the file.
        with_scale => scale: f32;
        /// Sets [`up`](Self::up): the file's up axis.
        with_up => up: UpAxis;
        /// Sets [`offset`](Self::offset): the offset in the body's frame, metres.
        with_offset => offset: [f32; 3];
        /// Sets [`pins`](Self::pins): the pinned vertices.
        with_pins => pins: Pins;
        /// Sets [`material`](Self::material): every vertex's material (`None`: the default).
        with_material => material: Option<Material>;
    }
}

/// A garment mesh of the user's and how to make it a [`Garment`] ([`garment_from_mesh`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OwnGarment<'a> {
    /// What it is, for the scene's name.
    pub name: &'a str,
    /// Positions in the file's units and frame.
    pub positions: &'a [[f32; 3]],
    /// Triangles.
    pub triangles: &'a [[u32; 3]],
    /// Scale, up axis, pins, material.
    pub options: &'a GarmentOptions,
}

impl OwnGarment<'_> {
    /// The garment, around `body` standing at `body_pos` ([`garment_from_mesh`]).
    ///
    /// # Errors
    /// As [`garment_from_mesh`].
    pub fn garment(&self, body: &BodyMesh, body_pos: &[[f32; 3]]) -> Result<Garment> {
        garment_from_mesh(self.positions, self.triangles, self.options, body, body_pos)
    }
}

/// A garment whose highest point is below this fraction of the body's height (measured from the
/// body's lowest point) has nothing to hang from (trousers, skirts): [`auto_pins`] pins it.
pub const HANGING_HEIGHT: f32 = 0.75;

/// [`auto_pins`] pins only a boundary loop whose mean distance to the body surface is at most
/// this, m: a waistband, not a hem.
pub const AUTO_PIN_REACH: f32 = 0.03;

/// A [`Garment`] of `positions` (in the file's units and frame) and `triangles`, transformed by
/// `options` into the body's frame (m, y up), made of its material and pinned as it says. `body_pos` is the
/// body (`body`) as the garment was modelled around it, for [`Pins::Auto`].
///
/// # Errors
/// [`Error::OutOfRange`] for a scale that is not finite and positive; errors of
/// [`Garment::new`] (the mesh's validation, an invalid material); [`Error::IndexOutOfRange`]
/// for a pinned index past the garment; errors of [`auto_pins`].
pub fn garment_from_mesh(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    options: &GarmentOptions,
    body: &BodyMesh,
    body_pos: &[[f32; 3]],
) -> Result<Garment> {
    if !(options.scale.is_finite() && options.scale > 0.0) {
        return Err(Error::OutOfRange { what: "garment scale", index: 0 });
    }
    let mut rest: Vec<[f32; 3]> =
        positions.iter().map(|&p| add3(scale3(options.up.to_y_up(p), options.scale), options.offset)).collect();
    // A garment modelled into the body (a tight fit, a proxy drawn on the skin) rests outside it:
    // a rest shape inside would pull the garment back in at every step.
    let fixed = match &options.pins {
        Pins::Vertices(v) => pinned_flags(rest.len(), v)?,
        _ => vec![false; rest.len()],
    };
    crate::solve::push_out_of(body, body_pos, &mut rest, &fixed)?;
    let materials = vec![options.material.unwrap_or_default(); rest.len()];
    let mut garment = Garment::new(GarmentDesc::new(&rest, triangles).materials(&materials))?;
    let pins = match &options.pins {
        Pins::None => Vec::new(),
        Pins::Auto => auto_pins(&garment, body, body_pos)?,
        Pins::Vertices(v) => v.clone(),
    };
    if !pins.is_empty() {
        garment.set_pinned(&pinned_flags(garment.n_vertices(), &pins)?)?;
    }
    Ok(garment)
}

/// The pins a garment needs not to fall, as the MakeHuman jeans are pinned, for each connected
/// piece of it (an outfit of a top and trousers in one mesh): none for a piece that reaches the
/// shoulders (its highest point above [`HANGING_HEIGHT`] of the body's height); otherwise the
/// piece's highest boundary loop among those within [`AUTO_PIN_REACH`] of the body (its
/// waistband). Ascending. The body stands y up at `body_pos`, the garment at its rest positions
/// around it.
///
/// # Errors
/// [`Error::Empty`] when a piece needs pins and none of its boundary loops lies within reach
/// (pin it by hand); errors of the body queries.
pub fn auto_pins(garment: &Garment, body: &BodyMesh, body_pos: &[[f32; 3]]) -> Result<Vec<u32>> {
    body.check_positions(body_pos)?;
    let (low, high) = body_pos.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), p| (l.min(p[1]), h.max(p[1])));
    let rest = garment.rest();
    let piece = garment.component_of();
    let mut top = vec![f32::NEG_INFINITY; garment.n_components()];
    for (p, &c) in rest.iter().zip(piece) {
        top[c as usize] = top[c as usize].max(p[1]);
    }
    let hanging: Vec<bool> = top.iter().map(|&t| t <= low + HANGING_HEIGHT * (high - low)).collect();
    if !hanging.contains(&true) {
        return Ok(Vec::new());
    }
    let surface = SurfaceDistance::new(body, body_pos)?;
    // Per piece: the height of its highest loop within reach, and that loop.
    let mut best: Vec<Option<(f32, &Vec<u32>)>> = vec![None; hanging.len()];
    for l in garment.boundary_loops() {
        let Some(&first) = l.first() else { continue };
        let c = piece[first as usize] as usize;
        if !hanging[c] {
            continue;
        }
        let points: Vec<[f32; 3]> = l.iter().map(|&v| rest[v as usize]).collect();
        let distance = surface.distances(&points)?.iter().sum::<f32>() / points.len() as f32;
        let height = points.iter().map(|p| p[1]).sum::<f32>() / points.len() as f32;
        if distance <= AUTO_PIN_REACH && best[c].is_none_or(|(h, _)| height > h) {
            best[c] = Some((height, l));
        }
    }
    let mut v = Vec::new();
    for (c, b) in best.iter().enumerate() {
        match b {
            Some((_, l)) => v.extend_from_slice(l),
            // The message reads "<what> is empty".
            None if hanging[c] => {
                return Err(Error::Empty {
                    what: "for automatic pins, the set of boundary loops within 3 cm of the body",
                })
            }
            None => {}
        }
    }
    v.sort_unstable();
    v.dedup();
    Ok(v)
}

/// Distances from points to a body surface: to the face whose centroid is nearest.
struct SurfaceDistance<'a> {
    frame: BodyFrame,
    body: &'a BodyMesh,
    body_pos: &'a [[f32; 3]],
}

impl<'a> SurfaceDistance<'a> {
    fn new(body: &'a BodyMesh, body_pos: &'a [[f32; 3]]) -> Result<Self> {
        let mut frame = BodyFrame::new(body)?;
        frame.update(body, body_pos)?;
        Ok(SurfaceDistance { frame, body, body_pos })
    }

    /// The nearest face of each point.
    fn faces(&self, points: &[[f32; 3]]) -> Result<Vec<u32>> {
        let mut near = vec![Nearest { index: 0, distance: 0.0 }; points.len()];
        self.frame.nearest_faces(points, &mut near)?;
        Ok(near.iter().map(|n| n.index).collect())
    }

    fn distances(&self, points: &[[f32; 3]]) -> Result<Vec<f32>> {
        let faces = self.faces(points)?;
        Ok(points
            .iter()
            .zip(&faces)
            .map(|(&p, &f)| {
                let [a, b, c] = self.body.faces()[f as usize].map(|k| Vec3::from(self.body_pos[k as usize]));
                point_triangle_distance(Vec3::from(p), a, b, c)
            })
            .collect())
    }
}

/// Garment vertices riding on a body given frame by frame: each keeps its barycentric place on
/// the plane of the body face nearest it in the reference frame and its offset along that
/// face's normal.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceAttachment {
    vertex: Vec<u32>,
    face: Vec<u32>,
    barycentric: Vec<[f32; 3]>,
    offset: Vec<f32>,
}

impl FaceAttachment {
    /// Attaches the garment vertices `vertices` (indices into `points`) to `body` at `body_pos`.
    ///
    /// # Errors
    /// [`Error::IndexOutOfRange`] for a vertex past `points`; errors of the body queries.
    pub fn new(body: &BodyMesh, body_pos: &[[f32; 3]], points: &[[f32; 3]], vertices: &[u32]) -> Result<Self> {
        let chosen = vertices
            .iter()
            .enumerate()
            .map(|(at, &v)| {
                points.get(v as usize).copied().ok_or(Error::IndexOutOfRange {
                    what: "attached vertex",
                    at,
                    index: v as usize,
                    len: points.len(),
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let faces = SurfaceDistance::new(body, body_pos)?.faces(&chosen)?;
        let mut barycentric = Vec::with_capacity(chosen.len());
        let mut offset = Vec::with_capacity(chosen.len());
        for (&p, &f) in chosen.iter().zip(&faces) {
            let [a, b, c] = body.faces()[f as usize].map(|k| body_pos[k as usize]);
            let (n, area2) = unit_normal(a, b, c);
            let d = dot3(sub3(p, a), n);
            let q = sub3(p, scale3(n, d));
            // Barycentric coordinates of q from the sub-triangle areas (signed along n).
            let w = |u: [f32; 3], v: [f32; 3]| dot3(cross3(sub3(u, q), sub3(v, q)), n) / area2.max(f32::MIN_POSITIVE);
            barycentric.push([w(b, c), w(c, a), w(a, b)]);
            offset.push(d);
        }
        Ok(FaceAttachment { vertex: vertices.to_vec(), face: faces, barycentric, offset })
    }

    /// Writes the attached vertices' positions on the body at `body_pos` into `out` (one entry
    /// per garment vertex; the others are left as they are).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for `body_pos` not one entry per body vertex;
    /// [`Error::IndexOutOfRange`] for `out` shorter than the attached vertices need.
    pub fn place(&self, body: &BodyMesh, body_pos: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<()> {
        body.check_positions(body_pos)?;
        for (k, &v) in self.vertex.iter().enumerate() {
            let [a, b, c] = body.faces()[self.face[k] as usize].map(|i| body_pos[i as usize]);
            let (n, _) = unit_normal(a, b, c);
            let [wa, wb, wc] = self.barycentric[k];
            let on_plane = add3(add3(scale3(a, wa), scale3(b, wb)), scale3(c, wc));
            let len = out.len();
            *out.get_mut(v as usize).ok_or(Error::IndexOutOfRange {
                what: "attached vertex",
                at: k,
                index: v as usize,
                len,
            })? = add3(on_plane, scale3(n, self.offset[k]));
        }
        Ok(())
    }
}

/// The unit normal of triangle `abc` and twice its area.
fn unit_normal(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> ([f32; 3], f32) {
    let n = cross3(sub3(b, a), sub3(c, a));
    let area2 = norm3(n);
    (if area2 > 0.0 { scale3(n, 1.0 / area2) } else { [0.0, 1.0, 0.0] }, area2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::procedural::Mannequin;
    use crate::scene::{procedural, GarmentKind, MotionKind};

    fn worn(kind: GarmentKind) -> (crate::scene::Scene, Mannequin) {
        let m = Mannequin::new();
        (procedural(&m, kind, 600, MotionKind::Walk, 0.2).unwrap(), m)
    }

    #[test]
    fn auto_pins_take_the_top_ring_of_a_skirt_and_a_strapless_dress() {
        for kind in [GarmentKind::Skirt, GarmentKind::Dress] {
            let (scene, m) = worn(kind);
            let g = &scene.garment;
            // The procedural garments' own pins are their top rings.
            assert_eq!(auto_pins(g, &scene.body, m.rest()).unwrap(), g.pinned_indices(), "{kind:?}");
        }
    }

    #[test]
    fn auto_pins_leave_a_garment_that_reaches_the_shoulders_free() {
        let (dress, m) = worn(GarmentKind::Dress);
        // The strapless dress (top at mid-chest) raised 30 cm: it reaches the shoulders.
        let rest: Vec<[f32; 3]> = dress.garment.rest().iter().map(|p| [p[0], p[1] + 0.3, p[2]]).collect();
        let raised = Garment::new(GarmentDesc::new(&rest, dress.garment.faces())).unwrap();
        assert!(auto_pins(&raised, &dress.body, m.rest()).unwrap().is_empty());
    }

    #[test]
    fn auto_pins_treat_each_piece_of_an_outfit_alone() {
        let (skirt, m) = worn(GarmentKind::Skirt);
        let (dress, _) = worn(GarmentKind::Dress);
        // A top that reaches the shoulders (the dress raised 30 cm) and the skirt, in one mesh.
        let mut rest: Vec<[f32; 3]> = dress.garment.rest().iter().map(|p| [p[0], p[1] + 0.3, p[2]]).collect();
        let offset = rest.len() as u32;
        rest.extend_from_slice(skirt.garment.rest());
        let mut faces = dress.garment.faces().to_vec();
        faces.extend(skirt.garment.faces().iter().map(|f| f.map(|v| v + offset)));
        let outfit = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
        let want: Vec<u32> = skirt.garment.pinned_indices().iter().map(|v| v + offset).collect();
        assert_eq!(auto_pins(&outfit, &skirt.body, m.rest()).unwrap(), want);
    }

    #[test]
    fn a_skirt_held_off_the_body_cannot_be_pinned_automatically() {
        let (skirt, m) = worn(GarmentKind::Skirt);
        // Widen the skirt about the body's vertical axis so that no loop is within reach.
        let rest: Vec<[f32; 3]> = skirt.garment.rest().iter().map(|p| [p[0] * 3.0, p[1], p[2] * 3.0]).collect();
        let wide = Garment::new(GarmentDesc::new(&rest, skirt.garment.faces())).unwrap();
        assert!(matches!(auto_pins(&wide, &skirt.body, m.rest()), Err(Error::Empty { .. })));
    }

    #[test]
    fn garment_options_scale_turn_pin_and_dress_the_mesh() {
        let (skirt, m) = worn(GarmentKind::Skirt);
        // The skirt as a z-up file in centimetres.
        let file: Vec<[f32; 3]> =
            skirt.garment.rest().iter().map(|p| [p[0] * 100.0, -p[2] * 100.0, p[1] * 100.0]).collect();
        let material = Material::preset("stiff-stretch").unwrap();
        let options = GarmentOptions {
            scale: 0.01,
            up: UpAxis::Z,
            pins: Pins::Auto,
            material: Some(material),
            ..Default::default()
        };
        let g = garment_from_mesh(&file, skirt.garment.faces(), &options, &skirt.body, m.rest()).unwrap();
        for (a, b) in g.rest().iter().zip(skirt.garment.rest()) {
            assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-5), "{a:?} vs {b:?}");
        }
        assert_eq!(g.pinned(), skirt.garment.pinned());
        assert!(g.materials().iter().all(|x| *x == material));
        let listed = GarmentOptions { pins: Pins::Vertices(vec![3, 1]), ..options.clone() };
        let g = garment_from_mesh(&file, skirt.garment.faces(), &listed, &skirt.body, m.rest()).unwrap();
        assert_eq!(g.pinned_indices(), [1, 3]);
        let past = GarmentOptions { pins: Pins::Vertices(vec![u32::MAX]), ..options.clone() };
        let e = garment_from_mesh(&file, skirt.garment.faces(), &past, &skirt.body, m.rest()).unwrap_err();
        assert!(matches!(e, Error::IndexOutOfRange { .. }), "{e}");
        let bad = GarmentOptions { scale: 0.0, ..options };
        let e = garment_from_mesh(&file, skirt.garment.faces(), &bad, &skirt.body, m.rest()).unwrap_err();
        assert!(matches!(e, Error::OutOfRange { what: "garment scale", .. }), "{e}");
    }

    #[test]
    fn attached_vertices_follow_a_rigid_motion_of_the_body_exactly() {
        let (skirt, m) = worn(GarmentKind::Skirt);
        let g = &skirt.garment;
        let pinned = g.pinned_indices();
        assert!(!pinned.is_empty());
        let attached = FaceAttachment::new(&skirt.body, m.rest(), g.rest(), &pinned).unwrap();
        // In place, every attached vertex lands where it is.
        let mut out = g.rest().to_vec();
        attached.place(&skirt.body, m.rest(), &mut out).unwrap();
        for &v in &pinned {
            let (a, b) = (out[v as usize], g.rest()[v as usize]);
            assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-5), "{a:?} vs {b:?}");
        }
        // Turned and moved with the body, they turn and move with it.
        let turn = glam::Quat::from_rotation_y(0.7) * glam::Quat::from_rotation_x(0.3);
        let shift = Vec3::new(0.4, -0.2, 1.5);
        let moved = |p: [f32; 3]| (turn * Vec3::from(p) + shift).to_array();
        let body: Vec<[f32; 3]> = m.rest().iter().map(|&p| moved(p)).collect();
        attached.place(&skirt.body, &body, &mut out).unwrap();
        for &v in &pinned {
            let (a, b) = (out[v as usize], moved(g.rest()[v as usize]));
            assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-5), "{a:?} vs {b:?}");
        }
        assert!(attached.place(&skirt.body, &body, &mut out[..1]).is_err());
    }

    #[test]
    fn up_axes_parse_and_turn() {
        assert_eq!(UpAxis::parse("z"), Some(UpAxis::Z));
        assert_eq!(UpAxis::parse("x"), None);
        assert_eq!(UpAxis::Z.to_y_up([1.0, 2.0, 3.0]), [1.0, 3.0, -2.0]);
        assert_eq!(UpAxis::Y.to_y_up([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0]);
    }
}
