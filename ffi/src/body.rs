//! The body: its descriptor (`hood_body_desc`), its survey, and pushing a garment out of it.

use crate::arrays::{byte_len_ok, disjoint, points, points_mut, require, slice, write_out};
use crate::extensible::{read_struct, write_extensible, Extensible};
use crate::guard::guard;
use crate::sim::{hood_sim, sim_ref};
use crate::status::{hood_status, Result};
use hood::body::BodyMesh;
use hood::Error;

/// The body of a scene (see the header).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct hood_body_desc {
    /// `sizeof(hood_body_desc)` in the caller's header (see its Conventions).
    pub struct_size: u32,
    /// First-frame positions, 3 floats per vertex.
    pub positions: *const f32,
    /// Vertex count.
    pub n_vertices: usize,
    /// 3 indices per face.
    pub indices: *const u32,
    /// Face count.
    pub n_faces: usize,
    /// Optional omitted flags (NULL: none).
    pub omitted: *const u8,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers and raw pointers.
unsafe impl Extensible for hood_body_desc {
    const NAME: &'static str = "hood_body_desc";
}

/// Reads a body descriptor: the struct as given, the mesh (with its omitted flags) and the
/// first-frame positions.
///
/// # Safety
/// `body` is NULL (refused) or holds the `struct_size` bytes it states, and its arrays hold the
/// documented counts, unchanged during the call.
pub(crate) unsafe fn read_body<'a>(body: *const hood_body_desc) -> Result<(hood_body_desc, BodyMesh, &'a [[f32; 3]])> {
    // SAFETY: `struct_size` readable bytes (caller); NULL is refused.
    let b = unsafe { read_struct(body, "body")? };
    require(b.positions, "body positions")?;
    require(b.indices, "body indices")?;
    // Absurd counts are refused before any array is viewed or anything allocated.
    hood::limits::body(b.n_vertices, b.n_faces)?;
    // SAFETY: counts are the caller's promise.
    let pos = unsafe { points(b.positions, b.n_vertices, "body positions")? };
    // SAFETY: as above.
    let faces = unsafe { slice(b.indices as *const [u32; 3], b.n_faces, "body indices")? };
    let mut mesh = BodyMesh::new(b.n_vertices, faces)?;
    if !b.omitted.is_null() {
        // SAFETY: as above.
        let om: Vec<bool> =
            unsafe { slice(b.omitted, b.n_vertices, "body omitted")? }.iter().map(|&o| o != 0).collect();
        mesh = mesh.with_omitted(&om)?;
    }
    Ok((b, mesh, pos))
}

/// Orientation and resolution of a sim's body (see the header).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct hood_body_survey {
    /// `sizeof(hood_body_survey)` in the caller's header, set before the call.
    pub struct_size: u32,
    /// Signed volume at the first frame, m³ (positive: wound outward).
    pub volume: f32,
    /// Median face edge, m.
    pub median_edge: f32,
    /// Longest face edge, m.
    pub longest_edge: f32,
    /// 1 when the median edge is too long for the body edges' radius (cloth may fall between
    /// the body's vertices), else 0.
    pub too_coarse: u32,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers and floats.
unsafe impl Extensible for hood_body_survey {
    const NAME: &'static str = "hood_body_survey";
}

/// The survey of the sim's body (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or a `hood_body_survey` of the
/// `struct_size` it states.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_body_survey(sim: *const hood_sim, out: *mut hood_body_survey) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        let survey =
            s.sim.body_survey().ok_or(Error::UnsupportedEffect { effect: "body survey (the sim has no body)" })?;
        let v = hood_body_survey {
            struct_size: 0,
            volume: survey.volume as f32,
            median_edge: survey.median_edge,
            longest_edge: survey.longest_edge,
            too_coarse: survey.too_coarse_for(hood::sim::BODY_EDGE_RADIUS) as u32,
        };
        // SAFETY: `out` is a `hood_body_survey` of its `struct_size` (caller).
        unsafe { write_extensible(out, v, "out") }
    })
}

/// Pushes a garment's unpinned vertices out of the body at its first frame, in place (see the
/// header): [`hood::solve::push_out_of`] on the caller's arrays.
///
/// # Safety
/// `body` is NULL or holds the `struct_size` bytes it states, with arrays of the stated counts;
/// `positions` is NULL or holds `3 * n_vertices` floats; `pinned` is NULL or holds `n_vertices`
/// bytes; `moved` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_garment_push_out(
    body: *const hood_body_desc,
    positions: *mut f32,
    n_vertices: usize,
    pinned: *const u8,
    moved: *mut usize,
) -> hood_status {
    guard(|| {
        require(body, "body")?;
        require(positions, "positions")?;
        // SAFETY: the caller's promise.
        let (b, mesh, body_pos) = unsafe { read_body(body)? };
        // Absurd counts are refused before anything is allocated (as `hood_garment_new` does).
        hood::limits::garment(n_vertices, 0)?;
        // The in/out array overlaps no input (checked before any of it is read as a slice).
        byte_len_ok::<[f32; 3]>(n_vertices)?;
        let point = size_of::<[f32; 3]>();
        let out = (positions.cast_const().cast::<u8>(), n_vertices * point);
        for (input, len) in [
            (b.positions.cast::<u8>(), b.n_vertices.saturating_mul(point)),
            (b.indices.cast::<u8>(), b.n_faces.saturating_mul(size_of::<[u32; 3]>())),
            (b.omitted, if b.omitted.is_null() { 0 } else { b.n_vertices }),
            (pinned, if pinned.is_null() { 0 } else { n_vertices }),
        ] {
            disjoint(input, len, out.0, out.1, "positions")?;
        }
        if mesh.survey(body_pos)?.inside_out() {
            return Err(Error::InsideOut { what: "body" }.into());
        }
        // SAFETY: `3 * n_vertices` readable floats (caller), overlapping no other input.
        let mut x = unsafe { points(positions, n_vertices, "positions")? }.to_vec();
        if let Some(i) = x.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(Error::NonFinite { what: "garment position", index: i }.into());
        }
        let pins: Vec<bool> = if pinned.is_null() {
            Vec::new()
        } else {
            // SAFETY: `n_vertices` readable bytes (caller).
            unsafe { slice(pinned, n_vertices, "pinned")? }.iter().map(|&p| p != 0).collect()
        };
        let count = hood::solve::push_out_of(&mesh, body_pos, &mut x, &pins)?;
        // Written only now, on success.
        // SAFETY: `3 * n_vertices` writable floats (caller), overlapping no input (checked).
        unsafe { points_mut(positions, n_vertices, "positions")? }.copy_from_slice(&x);
        if !moved.is_null() {
            // SAFETY: non-null; writable by the caller's promise.
            unsafe { write_out(moved, count) };
        }
        Ok(())
    })
}
