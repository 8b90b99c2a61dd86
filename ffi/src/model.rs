//! Model handles: loading `.hood` bytes in place, freeing, and describing a model.

use crate::arrays::{require, slice, slice_mut, write_out};
use crate::consts::{HOOD_EFFECT_BODY_COLLISION, HOOD_EFFECT_PINNING};
use crate::extensible::{struct_size, write_extensible, Extensible};
use crate::guard::guard;
use crate::registry::{register, unregister, use_live, Kind};
use crate::status::{hood_status, Failure, Result};
use hood::model::Model;
use hood::Error;
use std::ffi::c_char;
use std::sync::atomic::{AtomicUsize, Ordering};

/// A loaded model viewing caller-owned bytes.
pub struct hood_model {
    /// Borrows the caller's bytes; `'static` stands for "until `hood_model_free`" (the caller's
    /// promise, documented in the header).
    pub(crate) model: Model<'static>,
    /// Live sims borrowing `model`; changed only under the registry lock.
    pub(crate) sims: AtomicUsize,
    /// The file's format version (its header's second word).
    format_version: u32,
}

/// Validates a `.hood` buffer and views it in place (see the header for the lifetime rules).
///
/// # Safety
/// `bytes` points to `len` readable bytes that stay valid and unmodified until the model is
/// freed; `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_model_load(bytes: *const u8, len: usize, out: *mut *mut hood_model) -> hood_status {
    guard(|| {
        require(out, "out")?;
        require(bytes, "bytes")?;
        // SAFETY: non-null; the caller promises `len` readable bytes that outlive the model
        // handle unmodified, which is what the erased `'static` lifetime stands for.
        let data: &'static [u8] = unsafe { slice(bytes, len, "bytes")? };
        let model = Model::from_bytes(data)?;
        // The header that `from_bytes` validated: magic, then the little-endian format version.
        let format_version = u32::from_le_bytes([data[8], data[9], data[10], data[11]]);
        let h = register(Box::new(hood_model { model, sims: AtomicUsize::new(0), format_version }), Kind::Model);
        // SAFETY: `out` checked non-null above.
        unsafe { write_out(out, h) };
        Ok(())
    })
}

/// Frees a model; refused with `HOOD_ERR_MODEL_IN_USE` while sims use it.
///
/// # Safety
/// `model` is NULL or a pointer returned by `hood_model_load` (checked against the registry).
#[no_mangle]
pub unsafe extern "C" fn hood_model_free(model: *mut hood_model) -> hood_status {
    guard(|| {
        if model.is_null() {
            return Ok(());
        }
        // The sims are counted under the registry's lock, which `unregister` holds.
        let sims_left = |m: &hood_model| match m.sims.load(Ordering::SeqCst) {
            0 => Ok(()),
            n => Err(Failure::InUse(n)),
        };
        unregister(model, Kind::Model, "model", sims_left).map(drop)
    })
}

/// Whether the model holds bf16 weights (1) or not (0).
///
/// # Safety
/// `model` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_model_has_bf16(model: *const hood_model, out: *mut u32) -> hood_status {
    guard(|| {
        let _use = use_live(model, Kind::Model, "model")?;
        require(out, "out")?;
        // SAFETY: a live model handle.
        let m = unsafe { &*model };
        // SAFETY: `out` checked non-null.
        unsafe { write_out(out, m.model.has_bf16() as u32) };
        Ok(())
    })
}

/// What a model is (see the header).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct hood_model_info {
    /// `sizeof(hood_model_info)` in the caller's header, set before the call.
    pub struct_size: u32,
    /// The `.hood` format version of the file.
    pub format_version: u32,
    /// Latent width h.
    pub latent: u32,
    /// Hidden layers per MLP.
    pub hidden_layers: u32,
    /// Processor blocks.
    pub blocks: u32,
    /// Coarse levels of the hierarchy.
    pub levels: u32,
    /// 1 when the file holds bf16 weights too.
    pub has_bf16: u32,
    /// Effects trained with (`HOOD_EFFECT_BODY_COLLISION`, `HOOD_EFFECT_PINNING`).
    pub effects: u32,
    /// 1 when trained with per-vertex materials.
    pub local_materials: u32,
    /// One step's time, s.
    pub frame_time: f32,
    /// Metres per length unit of positions (1).
    pub length_unit: f32,
    /// The up axis: 0 x, 1 y, 2 z.
    pub up_axis: u32,
    /// Learned parameters.
    pub parameters: usize,
    /// Bytes of the schedule text (`hood_model_text`), without the NUL.
    pub schedule_len: usize,
    /// Bytes of the provenance text (`hood_model_text`), without the NUL.
    pub provenance_len: usize,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers and floats.
unsafe impl Extensible for hood_model_info {
    const NAME: &'static str = "hood_model_info";
}

/// `hood_model_text`: the processor schedule.
pub const HOOD_MODEL_TEXT_SCHEDULE: u32 = 0;
/// `hood_model_text`: the provenance.
pub const HOOD_MODEL_TEXT_PROVENANCE: u32 = 1;

/// The text `hood_model_text` copies (see the header).
fn model_text(m: &Model<'_>, which: u32) -> Result<String> {
    match which {
        HOOD_MODEL_TEXT_SCHEDULE => Ok(hood::model::spec::format_schedule(&m.spec().blocks)),
        HOOD_MODEL_TEXT_PROVENANCE => Ok(m.provenance().map(|(k, v)| format!("{k}: {v}\n")).collect()),
        w => Err(Error::OutOfRange { what: "model text kind", index: w as usize }.into()),
    }
}

/// Describes a model (see the header).
///
/// # Safety
/// `model` is NULL or a handle (checked); `out` is NULL or a `hood_model_info` of the
/// `struct_size` it states.
#[no_mangle]
pub unsafe extern "C" fn hood_model_get_info(model: *const hood_model, out: *mut hood_model_info) -> hood_status {
    guard(|| {
        let _use = use_live(model, Kind::Model, "model")?;
        // SAFETY: a live model handle.
        let h = unsafe { &*model };
        let (m, spec) = (&h.model, h.model.spec());
        let flag = |on: bool, f: u32| if on { f } else { 0 };
        let info = hood_model_info {
            struct_size: struct_size::<hood_model_info>(),
            format_version: h.format_version,
            latent: spec.latent as u32,
            hidden_layers: spec.hidden_layers as u32,
            blocks: spec.blocks.len() as u32,
            levels: spec.levels as u32,
            has_bf16: m.has_bf16() as u32,
            effects: flag(spec.effects.body, HOOD_EFFECT_BODY_COLLISION)
                | flag(spec.effects.pinning, HOOD_EFFECT_PINNING),
            local_materials: spec.effects.local_materials as u32,
            frame_time: hood::features::DT,
            length_unit: 1.0,
            up_axis: 1,
            parameters: spec.parameter_count(),
            schedule_len: model_text(m, HOOD_MODEL_TEXT_SCHEDULE)?.len(),
            provenance_len: model_text(m, HOOD_MODEL_TEXT_PROVENANCE)?.len(),
        };
        // SAFETY: the caller's promise.
        unsafe { write_extensible(out, info, "out") }
    })
}

/// Copies a model's text, NUL-terminated (see the header).
///
/// # Safety
/// `model` is NULL or a handle (checked); `out` is NULL or holds `len` writable bytes.
#[no_mangle]
pub unsafe extern "C" fn hood_model_text(
    model: *const hood_model,
    which: u32,
    out: *mut c_char,
    len: usize,
) -> hood_status {
    guard(|| {
        let _use = use_live(model, Kind::Model, "model")?;
        require(out, "out")?;
        // SAFETY: a live model handle.
        let text = model_text(&unsafe { &*model }.model, which)?;
        if len <= text.len() {
            return Err(Error::SizeMismatch {
                what: "model text buffer (text and NUL)",
                expected: text.len() + 1,
                got: len,
            }
            .into());
        }
        // SAFETY: `len` writable bytes (caller), more than the text.
        let buf = unsafe { slice_mut(out.cast::<u8>(), text.len() + 1, "out")? };
        buf[..text.len()].copy_from_slice(text.as_bytes());
        buf[text.len()] = 0;
        Ok(())
    })
}
