//! Garment handles: building a validated garment from the caller's arrays, freeing and counting.

use crate::arrays::{points, require, slice, write_out};
use crate::extensible::{read_struct_array, Extensible};
use crate::guard::guard;
use crate::registry::{register, unregister, use_live, Kind};
use crate::status::hood_status;
use hood::mesh::{Garment, GarmentDesc, Material};
use hood::Error;

/// Material of a cloth vertex, SI units.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct hood_material {
    /// `sizeof(hood_material)` in the caller's header (see its Conventions); an array's stride.
    pub struct_size: u32,
    /// Area density, kg/m^2.
    pub density: f32,
    /// Lamé mu, Pa.
    pub mu: f32,
    /// Lamé lambda, Pa.
    pub lambda: f32,
    /// Bending stiffness, J.
    pub bending: f32,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers and floats.
unsafe impl Extensible for hood_material {
    const NAME: &'static str = "hood_material";
}

/// A validated garment.
pub struct hood_garment {
    pub(crate) garment: Garment,
}

/// Builds a garment (see the header).
///
/// # Safety
/// Every non-NULL array holds the documented number of elements (`materials`: of
/// `materials[0].struct_size` bytes each); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_garment_new(
    rest: *const f32,
    n_vertices: usize,
    indices: *const u32,
    n_faces: usize,
    materials: *const hood_material,
    n_materials: usize,
    pinned: *const u8,
    out: *mut *mut hood_garment,
) -> hood_status {
    guard(|| {
        require(out, "out")?;
        require(rest, "rest")?;
        require(indices, "indices")?;
        // Absurd counts are refused before any array is viewed or anything allocated.
        hood::limits::garment(n_vertices, n_faces)?;
        if ![0, 1, n_vertices].contains(&n_materials) {
            return Err(Error::SizeMismatch { what: "materials", expected: n_vertices, got: n_materials }.into());
        }
        // SAFETY: array sizes are the caller's promise (header).
        let rest = unsafe { points(rest, n_vertices, "rest")? };
        // SAFETY: as above; `[u32; 3]` has u32 alignment and no padding.
        let faces = unsafe { slice(indices as *const [u32; 3], n_faces, "indices")? };
        // SAFETY: `n_materials` elements of `materials[0].struct_size` bytes (header).
        let mats = unsafe { read_struct_array(materials, n_materials, "materials")? };
        let mats: Vec<Material> = mats
            .iter()
            .map(|m| Material { density: m.density, mu: m.mu, lambda: m.lambda, bending: m.bending })
            .collect();
        let pins: Vec<bool> = if pinned.is_null() {
            Vec::new()
        } else {
            // SAFETY: as above.
            unsafe { slice(pinned, n_vertices, "pinned")? }.iter().map(|&p| p != 0).collect()
        };
        let garment = Garment::new(GarmentDesc::new(rest, faces).materials(&mats).pinned(&pins))?;
        let h = register(Box::new(hood_garment { garment }), Kind::Garment);
        // SAFETY: `out` checked non-null.
        unsafe { write_out(out, h) };
        Ok(())
    })
}

/// Frees a garment.
///
/// # Safety
/// `garment` is NULL or a handle (checked against the registry).
#[no_mangle]
pub unsafe extern "C" fn hood_garment_free(garment: *mut hood_garment) -> hood_status {
    guard(|| unregister(garment, Kind::Garment, "garment", |_| Ok(())).map(drop))
}

/// Number of garment vertices.
///
/// # Safety
/// `garment` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_garment_vertex_count(garment: *const hood_garment, out: *mut usize) -> hood_status {
    guard(|| {
        let _use = use_live(garment, Kind::Garment, "garment")?;
        require(out, "out")?;
        // SAFETY: a live garment handle; `out` non-null.
        unsafe { write_out(out, (*garment).garment.n_vertices()) };
        Ok(())
    })
}

/// Number of garment faces.
///
/// # Safety
/// `garment` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_garment_face_count(garment: *const hood_garment, out: *mut usize) -> hood_status {
    guard(|| {
        let _use = use_live(garment, Kind::Garment, "garment")?;
        require(out, "out")?;
        // SAFETY: a live garment handle; `out` non-null.
        unsafe { write_out(out, (*garment).garment.faces().len()) };
        Ok(())
    })
}
