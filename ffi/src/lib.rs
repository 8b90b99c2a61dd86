//! The C ABI of `hood`: opaque handles for model, garment and sim, status codes, a thread-local
//! last-error message, and an executor callback for an engine's job system.
//!
//! `include/hood.h` is the contract engines compile against; every item here has its twin there
//! (checked by `tests/header.rs`). The rules the caller must keep (lifetimes of model bytes,
//! threads) are stated in the header.
//!
//! Every export goes through `guard`, which catches panics; handles are checked (models and
//! garments against a registry of live handles, sims against their slots, without a lock), so
//! NULL, freed or mismatched handles give a status code.
#![deny(unsafe_op_in_unsafe_fn)]
// The C names of the types are the Rust names (the header check maps them one to one).
#![allow(non_camel_case_types)]

#[cfg_attr(not(feature = "allocator"), allow(dead_code))]
mod alloc;
mod log;
mod slots;

use glam::{Mat3, Quat, Vec3};
use hood::body::rigid::RigidMotion;
use hood::body::BodyMesh;
use hood::mesh::{Garment, GarmentDesc, Material};
use hood::model::Model;
use hood::sim::{
    BodyDesc, Executor, Interpolator, Precision, Serial, Sim, SimConfig, SimState, Sleeping, StepMode, ThreadPool,
};
use hood::Error;
use std::cell::RefCell;
use std::collections::BTreeMap;
use std::ffi::{c_char, c_void, CStr, CString};
use std::mem::ManuallyDrop;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::Mutex;

/// A status code: [`HOOD_OK`] or an error (codes 1-15 are [`Error::code`]).
pub type hood_status = u32;

/// Success.
pub const HOOD_OK: hood_status = 0;
/// [`Error::IndexOutOfRange`].
pub const HOOD_ERR_INDEX_OUT_OF_RANGE: hood_status = 1;
/// [`Error::NonFinite`].
pub const HOOD_ERR_NON_FINITE: hood_status = 2;
/// [`Error::DegenerateFace`].
pub const HOOD_ERR_DEGENERATE_FACE: hood_status = 3;
/// [`Error::RepeatedVertex`].
pub const HOOD_ERR_REPEATED_VERTEX: hood_status = 4;
/// [`Error::UnusedVertex`].
pub const HOOD_ERR_UNUSED_VERTEX: hood_status = 5;
/// [`Error::Empty`].
pub const HOOD_ERR_EMPTY: hood_status = 6;
/// [`Error::SizeMismatch`].
pub const HOOD_ERR_SIZE_MISMATCH: hood_status = 7;
/// [`Error::OutOfRange`].
pub const HOOD_ERR_OUT_OF_RANGE: hood_status = 8;
/// [`Error::CapacityExceeded`].
pub const HOOD_ERR_CAPACITY_EXCEEDED: hood_status = 9;
/// [`Error::IncompatibleModel`].
pub const HOOD_ERR_INCOMPATIBLE_MODEL: hood_status = 10;
/// [`Error::UnsupportedEffect`].
pub const HOOD_ERR_UNSUPPORTED_EFFECT: hood_status = 11;
/// [`Error::CorruptData`].
pub const HOOD_ERR_CORRUPT_DATA: hood_status = 12;
/// [`Error::Parse`].
pub const HOOD_ERR_PARSE: hood_status = 13;
/// [`Error::Io`].
pub const HOOD_ERR_IO: hood_status = 14;
/// [`Error::InsideOut`].
pub const HOOD_ERR_INSIDE_OUT: hood_status = 15;
/// A required pointer argument is NULL.
pub const HOOD_ERR_NULL_POINTER: hood_status = 100;
/// Not a live handle of the expected kind.
pub const HOOD_ERR_INVALID_HANDLE: hood_status = 101;
/// `hood_model_free` on a model that live sims use.
pub const HOOD_ERR_MODEL_IN_USE: hood_status = 102;
/// A panic was caught at the boundary.
pub const HOOD_ERR_PANIC: hood_status = 103;
/// A pointer argument is misaligned for its element type, or an output array overlaps an input.
pub const HOOD_ERR_BAD_POINTER: hood_status = 104;
/// The sim is in use by a call on another thread (a step, or a free while it steps).
pub const HOOD_ERR_BUSY: hood_status = 105;
/// A struct's `struct_size` is not one this library accepts: the caller was built against another
/// header (the rule is in the header's Conventions).
pub const HOOD_ERR_STRUCT_SIZE: hood_status = 106;

/// `hood_set_allocator` after the library has allocated.
pub const HOOD_ERR_TOO_LATE: hood_status = 107;

/// Required alignment of model bytes (`hood::model::file::ALIGN`).
pub const HOOD_MODEL_ALIGN: usize = hood::model::file::ALIGN;

/// Most vertices of a garment or a body (`hood::limits::MAX_VERTICES`).
pub const HOOD_MAX_VERTICES: usize = hood::limits::MAX_VERTICES;
/// Most triangles of a garment or a body (`hood::limits::MAX_FACES`).
pub const HOOD_MAX_FACES: usize = hood::limits::MAX_FACES;
/// Most bytes of a model file, and of the weights its spec needs (`hood::limits::MAX_MODEL_BYTES`).
pub const HOOD_MAX_MODEL_BYTES: usize = hood::limits::MAX_MODEL_BYTES;

/// Effect flag: collision with the body.
pub const HOOD_EFFECT_BODY_COLLISION: u32 = 1;
/// Effect flag: pinned vertices follow their targets.
pub const HOOD_EFFECT_PINNING: u32 = 2;
/// Effect flag: output vertex normals.
pub const HOOD_EFFECT_NORMALS: u32 = 4;
/// Effect flag: sleeping.
pub const HOOD_EFFECT_SLEEPING: u32 = 8;
/// Effect flag: start-up (relaxation) step.
pub const HOOD_EFFECT_STARTUP: u32 = 16;
/// Effect flag: carry the garment along when the body jumps farther than the threshold.
pub const HOOD_EFFECT_AUTO_TELEPORT: u32 = 32;
/// Body speeds beyond `speed_limit` carry the garment instead of reaching the network.
pub const HOOD_EFFECT_SPEED_LIMIT: u32 = 64;
/// Push garment vertices that end up within `projection_margin` of the body out to it.
pub const HOOD_EFFECT_COLLISION_PROJECTION: u32 = 128;
/// Refine every network step by `refine_iterations` L-BFGS iterations of the physics objective.
pub const HOOD_EFFECT_REFINE: u32 = 256;
const ALL_EFFECTS: u32 = 511;

/// Step flag: the garment was moved rigidly instead of stepped (a body jump, or
/// `hood_sim_teleport`).
pub const HOOD_STEP_TELEPORTED: u32 = 1;
/// Step flag: sleeping; the step was skipped.
pub const HOOD_STEP_SLEPT: u32 = 2;
/// Step flag: the start-up pass ran.
pub const HOOD_STEP_STARTUP: u32 = 4;
/// Step flag: the speed limit carried the garment.
pub const HOOD_STEP_SPEED_LIMITED: u32 = 8;
/// Step flag: a refinement (or the solver step mode's solve) ran.
pub const HOOD_STEP_REFINED: u32 = 16;
/// Step flag: the collision projection moved a vertex.
pub const HOOD_STEP_PROJECTED: u32 = 32;

/// Log level: an internal error (a panic caught at the boundary).
pub const HOOD_LOG_ERROR: u32 = 1;
/// Log level: a warning (e.g. a body too coarse for its collisions).
pub const HOOD_LOG_WARNING: u32 = 2;

/// f32 arithmetic.
pub const HOOD_PRECISION_F32: u32 = 0;
/// bf16 weights and activations.
pub const HOOD_PRECISION_BF16: u32 = 1;

const fn parse_u32(s: &str) -> u32 {
    let b = s.as_bytes();
    let mut v = 0;
    let mut i = 0;
    while i < b.len() {
        v = v * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    v
}

/// `HOOD_VERSION_MAJOR`, from Cargo.toml.
pub const HOOD_VERSION_MAJOR: u32 = parse_u32(env!("CARGO_PKG_VERSION_MAJOR"));
/// `HOOD_VERSION_MINOR`, from Cargo.toml.
pub const HOOD_VERSION_MINOR: u32 = parse_u32(env!("CARGO_PKG_VERSION_MINOR"));
/// `HOOD_VERSION_PATCH`, from Cargo.toml.
pub const HOOD_VERSION_PATCH: u32 = parse_u32(env!("CARGO_PKG_VERSION_PATCH"));

// ---- Errors ------------------------------------------------------------------------------------

/// Why a call failed.
enum Failure {
    Hood(Error),
    Null(&'static str),
    /// A pointer argument that is misaligned or overlaps another: (which, why).
    Pointer(&'static str, &'static str),
    Handle(&'static str),
    InUse(usize),
    /// A sim used by a call on another thread.
    Busy(&'static str),
    /// A `struct_size` this library does not accept: the whole message.
    StructSize(String),
    /// A call that must come before the library's first allocation.
    TooLate(&'static str),
}

impl From<Error> for Failure {
    fn from(e: Error) -> Self {
        Failure::Hood(e)
    }
}

impl Failure {
    fn code(&self) -> hood_status {
        match self {
            Failure::Hood(e) => e.code(),
            Failure::Null(_) => HOOD_ERR_NULL_POINTER,
            Failure::Pointer(..) => HOOD_ERR_BAD_POINTER,
            Failure::Handle(_) => HOOD_ERR_INVALID_HANDLE,
            Failure::InUse(_) => HOOD_ERR_MODEL_IN_USE,
            Failure::Busy(_) => HOOD_ERR_BUSY,
            Failure::StructSize(_) => HOOD_ERR_STRUCT_SIZE,
            Failure::TooLate(_) => HOOD_ERR_TOO_LATE,
        }
    }

    fn message(&self) -> String {
        match self {
            Failure::Hood(e) => e.to_string(),
            Failure::Null(what) => format!("{what} is NULL"),
            Failure::Pointer(what, why) => format!("{what} {why}"),
            Failure::Handle(what) => format!("{what} is not a live handle (already freed, or never created)"),
            Failure::InUse(n) => format!("the model is still used by {n} sim(s); free them first"),
            Failure::Busy(what) => {
                format!("{what} is in use by a call on another thread (one thread at a time per sim)")
            }
            Failure::StructSize(msg) => msg.clone(),
            Failure::TooLate(what) => format!("{what}: the library has allocated already (call it before any other)"),
        }
    }
}

type Result<T> = std::result::Result<T, Failure>;

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_last_error(msg: String) {
    let c = CString::new(msg.replace('\0', " ")).unwrap_or_default();
    // Ignore failure during thread teardown: there is nobody left to read the message.
    let _ = LAST_ERROR.try_with(|s| *s.borrow_mut() = c);
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic payload".to_string()
    }
}

/// Runs the body of an export: maps its error to a status code and the last-error message, and
/// catches any panic (reported as [`HOOD_ERR_PANIC`]).
fn guard(f: impl FnOnce() -> Result<()>) -> hood_status {
    let _inside = log::Inside::enter();
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => HOOD_OK,
        Ok(Err(e)) => {
            set_last_error(e.message());
            e.code()
        }
        Err(payload) => {
            // Formatting the message could itself panic (allocation failure): contain that too.
            let msg = catch_unwind(AssertUnwindSafe(|| panic_message(&*payload))).unwrap_or_default();
            let _ = catch_unwind(AssertUnwindSafe(|| {
                let text = match log::take_panic_location() {
                    Some(at) => format!("internal error (panic at {at}): {msg}"),
                    None => format!("internal error (panic): {msg}"),
                };
                log::log(HOOD_LOG_ERROR, &text);
                set_last_error(text);
            }));
            HOOD_ERR_PANIC
        }
    }
}

// ---- Handle registry ---------------------------------------------------------------------------

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Kind {
    Model,
    Garment,
}

/// Live model and garment handles by address. A handle is usable only while registered, which
/// turns use after free, double free and handles of the wrong kind into
/// [`HOOD_ERR_INVALID_HANDLE`]. Sims are not here: their handles are slots that calls check and
/// claim without a lock (see [`slots`]).
static LIVE: Mutex<BTreeMap<usize, Kind>> = Mutex::new(BTreeMap::new());

fn live() -> std::sync::MutexGuard<'static, BTreeMap<usize, Kind>> {
    // The map is updated by single inserts/removes, so a poisoned lock still holds a valid map.
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

fn register<T>(b: Box<T>, kind: Kind) -> *mut T {
    let p = Box::into_raw(b);
    live().insert(p as usize, kind);
    p
}

fn check_live<T>(p: *const T, kind: Kind, what: &'static str) -> Result<()> {
    if p.is_null() {
        return Err(Failure::Null(what));
    }
    match live().get(&(p as usize)) {
        Some(&k) if k == kind => Ok(()),
        _ => Err(Failure::Handle(what)),
    }
}

/// Removes a handle from the registry (the caller then owns the box); `Ok(None)` for NULL.
fn unregister<T>(p: *mut T, kind: Kind, what: &'static str) -> Result<Option<Box<T>>> {
    if p.is_null() {
        return Ok(None);
    }
    let mut reg = live();
    match reg.get(&(p as usize)) {
        Some(&k) if k == kind => {
            reg.remove(&(p as usize));
            // SAFETY: registered addresses come from `Box::into_raw` of a `T` of this kind (the
            // kind was checked) and are removed exactly once, here, so the box is still owned.
            Ok(Some(unsafe { Box::from_raw(p) }))
        }
        _ => Err(Failure::Handle(what)),
    }
}

// ---- Arrays ------------------------------------------------------------------------------------

fn byte_len_ok<T>(n: usize) -> Result<()> {
    match n.checked_mul(size_of::<T>()) {
        Some(b) if b <= isize::MAX as usize => Ok(()),
        _ => Err(Error::OutOfRange { what: "array length", index: n }.into()),
    }
}

/// `n` elements at `p` (NULL allowed when `n == 0`).
///
/// # Safety
/// `p` is NULL or points to `n` readable, initialised `T`s that stay unchanged during the call.
unsafe fn slice<'a, T>(p: *const T, n: usize, what: &'static str) -> Result<&'a [T]> {
    if n == 0 {
        return Ok(&[]);
    }
    if p.is_null() {
        return Err(Failure::Null(what));
    }
    aligned(p, what)?;
    byte_len_ok::<T>(n)?;
    // SAFETY: non-null, aligned, `n` elements readable (caller), total size checked above.
    Ok(unsafe { std::slice::from_raw_parts(p, n) })
}

/// `n` writable elements at `p` (NULL allowed when `n == 0`).
///
/// # Safety
/// `p` is NULL or points to `n` writable `T`s not aliased during the call.
unsafe fn slice_mut<'a, T>(p: *mut T, n: usize, what: &'static str) -> Result<&'a mut [T]> {
    if n == 0 {
        return Ok(&mut []);
    }
    if p.is_null() {
        return Err(Failure::Null(what));
    }
    aligned(p, what)?;
    byte_len_ok::<T>(n)?;
    // SAFETY: as in `slice`, and not aliased (caller).
    Ok(unsafe { std::slice::from_raw_parts_mut(p, n) })
}

/// Refuses a pointer that is not aligned for `T` (a slice over it would be undefined behaviour).
fn aligned<T>(p: *const T, what: &'static str) -> Result<()> {
    if p.is_aligned() {
        Ok(())
    } else {
        Err(Failure::Pointer(what, "is not aligned for its element type"))
    }
}

/// Refuses an output array of `out_len` elements of `T` that overlaps an input of `in_len`
/// (Rust may not hold a shared and a mutable view of the same memory at once).
fn disjoint<T>(input: *const T, in_len: usize, out: *const T, out_len: usize, what: &'static str) -> Result<()> {
    // A length whose byte size overflows is refused as such, not reported as an overlap.
    byte_len_ok::<T>(in_len)?;
    byte_len_ok::<T>(out_len)?;
    let size = size_of::<T>();
    let (a, b) = (input as usize, out as usize);
    let (a_end, b_end) = (a.saturating_add(in_len * size), b.saturating_add(out_len * size));
    if in_len == 0 || out_len == 0 || a_end <= b || b_end <= a {
        Ok(())
    } else {
        Err(Failure::Pointer(what, "overlaps an input array"))
    }
}

/// `n` points (3 floats each) at `p`.
///
/// # Safety
/// As [`slice`] for `3 * n` floats.
unsafe fn points<'a>(p: *const f32, n: usize, what: &'static str) -> Result<&'a [[f32; 3]]> {
    // SAFETY: `[f32; 3]` has the alignment of f32 and no padding; caller guarantees 3n floats.
    unsafe { slice(p as *const [f32; 3], n, what) }
}

/// # Safety
/// As [`slice_mut`] for `3 * n` floats.
unsafe fn points_mut<'a>(p: *mut f32, n: usize, what: &'static str) -> Result<&'a mut [[f32; 3]]> {
    // SAFETY: as in `points`.
    unsafe { slice_mut(p as *mut [f32; 3], n, what) }
}

fn expect_len(what: &'static str, expected: usize, got: usize) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(Error::SizeMismatch { what, expected, got }.into())
    }
}

/// Writes an out-parameter (after the call's work succeeded).
///
/// # Safety
/// `out` is NULL (checked) or valid for a write of `T`.
unsafe fn write_out<T>(out: *mut T, v: T) {
    // SAFETY: callers check `out` for NULL first; validity is the caller's promise.
    unsafe { out.write(v) }
}

fn require<T>(p: *const T, what: &'static str) -> Result<()> {
    if p.is_null() {
        Err(Failure::Null(what))
    } else {
        Ok(())
    }
}

// ---- Extensible structs ------------------------------------------------------------------------

/// A struct whose first field is `struct_size: u32`, the size of the struct in the header the
/// caller was built against: passed in (`hood_sim_config`, `hood_body_desc`, `hood_executor`,
/// `hood_material`) or filled in (`hood_model_info`, `hood_refinement`, `hood_body_survey`). It
/// lets the structs grow without old and new callers silently misreading each other;
/// [`read_extensible`] and [`write_extensible`] apply the rule.
///
/// # Safety
/// Implementors are `#[repr(C)]`, start with `struct_size: u32`, and have no invalid bit
/// patterns (integers, floats, raw pointers, optional function pointers), so that reading any
/// caller bytes as one is sound.
unsafe trait Extensible: Copy {
    /// The C name, for messages.
    const NAME: &'static str;
    /// The smallest `struct_size` accepted: the struct's size in the first release that had
    /// `struct_size` (fields added since read as zero from a caller built against it).
    const MIN_SIZE: usize = size_of::<Self>();
}

/// The `struct_size` of `T` in this library (what `hood_sim_config_default` writes).
const fn struct_size<T: Extensible>() -> u32 {
    size_of::<T>() as u32
}

/// Largest `struct_size` accepted (a page, as openat2 limits its struct): a garbage size must not
/// make the library scan megabytes of the caller's memory for nonzero bytes.
const MAX_STRUCT_SIZE: usize = 4096;

/// Reads an extensible struct through a caller pointer: the leading `struct_size` first, then,
/// if it is acceptable, the prefix this library knows. The rule is that of Linux's openat2 and
/// clone3, which lets callers built against an older or a newer header be told apart from
/// current ones instead of being misread:
///
/// - smaller than `size_of::<T>()`: an older header, whose fields this library would read past
///   the end of: refused;
/// - equal: the current header;
/// - larger: a newer header. Its extra fields are accepted only if every byte past
///   `size_of::<T>()` (up to `struct_size`) is zero, the value a newer field must give for
///   "unset" (a field set to anything else asks for something this library cannot do, so it is
///   refused rather than ignored);
/// - larger than [`MAX_STRUCT_SIZE`], or not a multiple of `T`'s alignment (which every C
///   `sizeof` is, and which keeps the elements of an array aligned): refused.
///
/// `stride` is `None` for a lone struct or the first element of an array (whose `struct_size`
/// becomes the array's stride), and the stride for the other elements, which must carry exactly
/// that `struct_size` (checked before any byte past it is read, so a bad element never makes
/// the library read beyond the array). `index` names the element in messages. Returns the value
/// and the caller's `struct_size`. Every refusal is [`HOOD_ERR_STRUCT_SIZE`] except a NULL
/// pointer ([`HOOD_ERR_NULL_POINTER`]) and a misaligned one ([`HOOD_ERR_BAD_POINTER`]).
///
/// # Safety
/// `p` is NULL or points to a struct whose leading `u32` is readable and which has at least
/// as many readable bytes as that `u32` says (`stride` for array elements), unchanged during
/// the call.
unsafe fn read_extensible<T: Extensible>(
    p: *const T,
    index: Option<usize>,
    stride: Option<usize>,
    what: &'static str,
) -> Result<(T, usize)> {
    require(p, what)?;
    // `T` starts with a u32, so this also aligns the leading read.
    aligned(p, what)?;
    // SAFETY: non-null and aligned; the leading u32 is readable (caller).
    let size = unsafe { p.cast::<u32>().read() } as usize;
    let refuse = |why: String| {
        let name = match index {
            Some(i) => format!("{}[{i}]", T::NAME),
            None => T::NAME.to_string(),
        };
        Err(Failure::StructSize(format!(
            "{name}.struct_size is {size}: {why} (the caller was built against another hood.h; \
             sizeof({}) is {} in this library)",
            T::NAME,
            size_of::<T>()
        )))
    };
    if let Some(stride) = stride {
        if size != stride {
            return refuse(format!("every element must carry the first element's struct_size, {stride}"));
        }
    }
    if let Some(why) = size_problem::<T>(size) {
        return refuse(why);
    }
    if size < size_of::<T>() {
        // An older header: its fields, and zeros for those added since ("unset").
        let mut out = std::mem::MaybeUninit::<T>::zeroed();
        // SAFETY: `size` bytes are readable (caller) and fit in `out`; all-zero bytes and any
        // bytes are valid for `T` (`Extensible`).
        unsafe {
            std::ptr::copy_nonoverlapping(p.cast::<u8>(), out.as_mut_ptr().cast::<u8>(), size);
            let mut t = out.assume_init();
            // The caller's struct_size stays as it wrote it.
            std::ptr::addr_of_mut!(t).cast::<u32>().write(size as u32);
            return Ok((t, size));
        }
    }
    // SAFETY: `size` bytes are readable (caller) and `size_of::<T>() <= size`, so the tail
    // `size_of::<T>()..size` is inside them.
    let tail = unsafe { std::slice::from_raw_parts(p.cast::<u8>().add(size_of::<T>()), size - size_of::<T>()) };
    if let Some(k) = tail.iter().position(|&b| b != 0) {
        return refuse(format!(
            "byte {} is not zero, past the {} bytes this library knows (a field it does not have is set)",
            size_of::<T>() + k,
            size_of::<T>()
        ));
    }
    // SAFETY: aligned, and at least `size_of::<T>()` readable bytes; any bytes are a valid `T`
    // (`Extensible`).
    Ok((unsafe { p.read() }, size))
}

/// Why `size` cannot be a `struct_size` of `T` (see [`read_extensible`]), or `None`.
fn size_problem<T: Extensible>(size: usize) -> Option<String> {
    if size < T::MIN_SIZE {
        Some(format!("smaller than the oldest header this library reads ({} bytes)", T::MIN_SIZE))
    } else if size > MAX_STRUCT_SIZE {
        Some(format!("larger than {MAX_STRUCT_SIZE} bytes"))
    } else if !size.is_multiple_of(align_of::<T>()) {
        Some(format!("not a multiple of the struct's alignment, {}", align_of::<T>()))
    } else {
        None
    }
}

/// One extensible struct (see [`read_extensible`]).
///
/// # Safety
/// As [`read_extensible`].
unsafe fn read_struct<T: Extensible>(p: *const T, what: &'static str) -> Result<T> {
    // SAFETY: the caller's promise.
    Ok(unsafe { read_extensible(p, None, None, what)? }.0)
}

/// An array of `n` extensible structs (NULL allowed when `n == 0`). The caller's element size is
/// `p[0].struct_size`, which every element must carry (see [`read_extensible`]).
///
/// # Safety
/// `p` is NULL or points to `n` elements of `p[0].struct_size` bytes each, readable and
/// unchanged during the call.
unsafe fn read_struct_array<T: Extensible>(p: *const T, n: usize, what: &'static str) -> Result<Vec<T>> {
    if n == 0 {
        return Ok(Vec::new());
    }
    // SAFETY: element 0 is readable (caller).
    let (first, stride) = unsafe { read_extensible(p, Some(0), None, what)? };
    match n.checked_mul(stride) {
        Some(b) if b <= isize::MAX as usize => {}
        _ => return Err(Error::OutOfRange { what: "array length", index: n }.into()),
    }
    let mut out = Vec::with_capacity(n);
    out.push(first);
    for i in 1..n {
        // SAFETY: inside the caller's `n * stride` bytes (checked not to overflow above); the
        // stride is a multiple of `T`'s alignment, so the element is aligned.
        let e = unsafe { p.byte_add(i * stride) };
        // SAFETY: the element's `stride` bytes are readable (caller); a different
        // `struct_size` is refused before any byte past `stride` is read.
        out.push(unsafe { read_extensible(e, Some(i), Some(stride), what)? }.0);
    }
    Ok(out)
}

/// Writes `v` into a caller's struct of `size` bytes: `v` with `struct_size` set to `size`, then
/// zeros up to `size` (a newer header's fields, "unset"); for an older header's smaller struct,
/// only its first `size` bytes. `size` must pass [`size_problem`].
///
/// # Safety
/// `out` is non-null, aligned and points to `size >= T::MIN_SIZE` writable bytes.
unsafe fn write_sized<T: Extensible>(out: *mut T, v: T, size: usize) {
    let known = size_of::<T>();
    // SAFETY: `size` writable bytes at an aligned `out` (caller); `T` starts with the `u32`
    // struct_size (`Extensible`).
    unsafe {
        if size >= known {
            write_out(out, v);
            std::ptr::write_bytes(out.cast::<u8>().add(known), 0, size - known);
        } else {
            std::ptr::copy_nonoverlapping((&v as *const T).cast::<u8>(), out.cast::<u8>(), size);
        }
        out.cast::<u32>().write(size as u32);
    }
}

/// Writes an extensible output struct (`hood_model_info`, `hood_refinement`, `hood_body_survey`)
/// whose `struct_size` the caller has set: checked as [`read_extensible`] checks an input's
/// (so an older header's smaller struct is never overrun), then filled by [`write_sized`].
///
/// # Safety
/// `out` is NULL or points to a struct whose leading `u32` is readable and which has at least as
/// many writable bytes as that `u32` says.
unsafe fn write_extensible<T: Extensible>(out: *mut T, v: T, what: &'static str) -> Result<()> {
    // SAFETY: the caller's promise; `read_extensible`'s checks of the size and alignment.
    let size = unsafe { struct_size_of(out, what)? };
    // SAFETY: checked above; `size` writable bytes (caller).
    unsafe { write_sized(out, v, size) };
    Ok(())
}

/// The caller's `struct_size` of an output struct at `out`, checked (see [`write_extensible`]).
///
/// # Safety
/// As [`write_extensible`].
unsafe fn struct_size_of<T: Extensible>(out: *const T, what: &'static str) -> Result<usize> {
    require(out, what)?;
    aligned(out, what)?;
    // SAFETY: non-null and aligned; the leading u32 is readable (caller).
    let size = unsafe { out.cast::<u32>().read() } as usize;
    match size_problem::<T>(size) {
        None => Ok(size),
        Some(why) => Err(Failure::StructSize(format!(
            "{}.struct_size is {size}: {why} (set it to sizeof({}) before the call; it is {} in this library)",
            T::NAME,
            T::NAME,
            size_of::<T>()
        ))),
    }
}

// ---- Version and errors ------------------------------------------------------------------------

/// The library version, `(major << 16) | (minor << 8) | patch`.
#[no_mangle]
pub extern "C" fn hood_version() -> u32 {
    (HOOD_VERSION_MAJOR << 16) | (HOOD_VERSION_MINOR << 8) | HOOD_VERSION_PATCH
}

/// The library version as a NUL-terminated string with static storage.
#[no_mangle]
pub extern "C" fn hood_version_string() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr() as *const c_char
}

/// The message of the most recent failing call on this thread ("" if none).
#[no_mangle]
pub extern "C" fn hood_last_error() -> *const c_char {
    static EMPTY: &CStr = c"";
    catch_unwind(|| LAST_ERROR.try_with(|s| s.borrow().as_ptr()).unwrap_or(EMPTY.as_ptr())).unwrap_or(EMPTY.as_ptr())
}

/// The name and meaning of a status code, as the header's comment on it states them (checked by
/// `tests/header.rs`); "unknown status" for a code this library does not have.
fn status_text(code: hood_status) -> &'static CStr {
    match code {
        HOOD_OK => c"HOOD_OK: success",
        HOOD_ERR_INDEX_OUT_OF_RANGE => c"HOOD_ERR_INDEX_OUT_OF_RANGE: an index (e.g. in a face) refers past the end",
        HOOD_ERR_NON_FINITE => c"HOOD_ERR_NON_FINITE: a coordinate or parameter is NaN or infinite",
        HOOD_ERR_DEGENERATE_FACE => c"HOOD_ERR_DEGENERATE_FACE: a garment triangle has zero area",
        HOOD_ERR_REPEATED_VERTEX => c"HOOD_ERR_REPEATED_VERTEX: a triangle names the same vertex twice",
        HOOD_ERR_UNUSED_VERTEX => c"HOOD_ERR_UNUSED_VERTEX: a garment vertex belongs to no triangle",
        HOOD_ERR_EMPTY => c"HOOD_ERR_EMPTY: something that must not be empty is",
        HOOD_ERR_SIZE_MISMATCH => c"HOOD_ERR_SIZE_MISMATCH: an array has the wrong length",
        HOOD_ERR_OUT_OF_RANGE => c"HOOD_ERR_OUT_OF_RANGE: a value is outside its documented range",
        HOOD_ERR_CAPACITY_EXCEEDED => c"HOOD_ERR_CAPACITY_EXCEEDED: a capacity fixed at creation, or a bound such as HOOD_MAX_VERTICES, was exceeded",
        HOOD_ERR_INCOMPATIBLE_MODEL => c"HOOD_ERR_INCOMPATIBLE_MODEL: the model cannot run this garment/body/config",
        HOOD_ERR_UNSUPPORTED_EFFECT => c"HOOD_ERR_UNSUPPORTED_EFFECT: an effect the model, the configuration or this build does not support",
        HOOD_ERR_CORRUPT_DATA => {
            c"HOOD_ERR_CORRUPT_DATA: model bytes corrupt, truncated, misaligned, other version"
        }
        HOOD_ERR_PARSE => c"HOOD_ERR_PARSE: a text input could not be parsed",
        HOOD_ERR_IO => c"HOOD_ERR_IO: an operating-system I/O failure",
        HOOD_ERR_INSIDE_OUT => c"HOOD_ERR_INSIDE_OUT: the body mesh is wound inside out (reverse every face)",
        HOOD_ERR_NULL_POINTER => c"HOOD_ERR_NULL_POINTER: a required pointer argument is NULL",
        HOOD_ERR_INVALID_HANDLE => c"HOOD_ERR_INVALID_HANDLE: not a live handle of that kind (freed, or never made)",
        HOOD_ERR_MODEL_IN_USE => c"HOOD_ERR_MODEL_IN_USE: hood_model_free on a model that live sims still use",
        HOOD_ERR_PANIC => c"HOOD_ERR_PANIC: an internal error (a bug in hood); the handle may be unusable",
        HOOD_ERR_BAD_POINTER => {
            c"HOOD_ERR_BAD_POINTER: a pointer misaligned for its type, or an output overlapping an input"
        }
        HOOD_ERR_BUSY => c"HOOD_ERR_BUSY: the sim is in use by a call on another thread",
        HOOD_ERR_STRUCT_SIZE => {
            c"HOOD_ERR_STRUCT_SIZE: struct_size is not one this library knows: the caller was built against another header"
        }
        HOOD_ERR_TOO_LATE => {
            c"HOOD_ERR_TOO_LATE: hood_set_allocator after the library has allocated (call it first)"
        }
        _ => c"unknown status",
    }
}

/// The name and meaning of a status code ("unknown status" for others): a NUL-terminated string
/// with static storage. Never fails, and leaves `hood_last_error` alone.
#[no_mangle]
pub extern "C" fn hood_status_string(code: hood_status) -> *const c_char {
    status_text(code).as_ptr()
}

/// The library's allocator: the system's, or the engine's (`hood_set_allocator`).
#[cfg(feature = "allocator")]
#[global_allocator]
static GLOBAL: alloc::Hooked = alloc::Hooked;

/// An engine's allocator (see the header).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct hood_allocator {
    /// `sizeof(hood_allocator)` in the caller's header (see its Conventions).
    pub struct_size: u32,
    /// Passed back to both functions.
    pub user: *mut c_void,
    /// Allocates `size` bytes aligned to `align` (NULL on failure).
    pub alloc: Option<unsafe extern "C" fn(size: usize, align: usize, user: *mut c_void) -> *mut c_void>,
    /// Frees a block of `alloc` with its size and alignment.
    pub free: Option<unsafe extern "C" fn(ptr: *mut c_void, size: usize, align: usize, user: *mut c_void)>,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, an integer, a raw pointer and optional function
// pointers.
unsafe impl Extensible for hood_allocator {
    const NAME: &'static str = "hood_allocator";
}

/// Routes the library's allocations to the engine (see the header).
///
/// # Safety
/// `allocator` is NULL or holds the `struct_size` bytes it states, and its functions keep the
/// header's contract for the life of the process.
#[no_mangle]
pub unsafe extern "C" fn hood_set_allocator(allocator: *const hood_allocator) -> hood_status {
    // Not through `guard`, which may allocate (the panic machinery, the last error): checks that
    // fail before the choice is made allocate only to report.
    if !cfg!(feature = "allocator") {
        return guard(|| Err(Error::UnsupportedEffect { effect: "allocator callbacks (built without them)" }.into()));
    }
    if allocator.is_null() {
        return guard(|| Err(Failure::Null("allocator")));
    }
    // SAFETY: non-null; `struct_size` readable bytes (caller). Reading allocates nothing.
    let a = match unsafe { read_extensible(allocator, None, None, "allocator") } {
        Ok((a, _)) => a,
        Err(e) => return guard(|| Err(e)),
    };
    let (Some(alloc), Some(free)) = (a.alloc, a.free) else {
        return guard(|| Err(Failure::Null("allocator alloc or free")));
    };
    if alloc::install(alloc::Hooks { alloc, free, user: a.user }) {
        HOOD_OK
    } else {
        guard(|| Err(Failure::TooLate("hood_set_allocator")))
    }
}

/// The log callback's type (`extern "C"` is cdecl on 32-bit Windows, as `HOOD_CALL` declares it).
pub type hood_log_fn = Option<unsafe extern "C" fn(level: u32, message: *const c_char, user: *mut c_void)>;

/// Sets (or with NULL removes) the log callback (see the header).
///
/// # Safety
/// `callback` is NULL or keeps the header's contract; `user` stays valid while it is set.
#[no_mangle]
pub unsafe extern "C" fn hood_set_log_callback(callback: hood_log_fn, user: *mut c_void) -> hood_status {
    guard(|| {
        log::set(callback, user);
        Ok(())
    })
}

// ---- Model -------------------------------------------------------------------------------------

/// A loaded model viewing caller-owned bytes.
pub struct hood_model {
    /// Borrows the caller's bytes; `'static` stands for "until `hood_model_free`" (the caller's
    /// promise, documented in the header).
    model: Model<'static>,
    /// Live sims borrowing `model`; changed only under the registry lock.
    sims: AtomicUsize,
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
        let mut reg = live();
        if reg.get(&(model as usize)) != Some(&Kind::Model) {
            return Err(Failure::Handle("model"));
        }
        // SAFETY: registered as a live model, so the pointer is a valid `hood_model`.
        let sims = unsafe { &*model }.sims.load(Ordering::SeqCst);
        if sims > 0 {
            return Err(Failure::InUse(sims));
        }
        reg.remove(&(model as usize));
        drop(reg);
        // SAFETY: it was registered (from `Box::into_raw`) and has just been unregistered.
        drop(unsafe { Box::from_raw(model) });
        Ok(())
    })
}

/// Whether the model holds bf16 weights (1) or not (0).
///
/// # Safety
/// `model` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_model_has_bf16(model: *const hood_model, out: *mut u32) -> hood_status {
    guard(|| {
        check_live(model, Kind::Model, "model")?;
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
        check_live(model, Kind::Model, "model")?;
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
        check_live(model, Kind::Model, "model")?;
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

// ---- Garment -----------------------------------------------------------------------------------

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
    garment: Garment,
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
    guard(|| unregister(garment, Kind::Garment, "garment").map(drop))
}

/// Number of garment vertices.
///
/// # Safety
/// `garment` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_garment_vertex_count(garment: *const hood_garment, out: *mut usize) -> hood_status {
    guard(|| {
        check_live(garment, Kind::Garment, "garment")?;
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
        check_live(garment, Kind::Garment, "garment")?;
        require(out, "out")?;
        // SAFETY: a live garment handle; `out` non-null.
        unsafe { write_out(out, (*garment).garment.faces().len()) };
        Ok(())
    })
}

// ---- Simulation --------------------------------------------------------------------------------

/// The sim's configuration (see the header).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct hood_sim_config {
    /// `sizeof(hood_sim_config)` in the caller's header (see its Conventions).
    pub struct_size: u32,
    /// `HOOD_EFFECT_*` flags.
    pub effects: u32,
    /// `HOOD_PRECISION_*`.
    pub precision: u32,
    /// Worker threads without an executor.
    pub threads: u32,
    /// Frames at rest before sleeping.
    pub sleep_frames: u32,
    /// "At rest" threshold, m/frame.
    pub sleep_threshold: f32,
    /// Auto-teleport threshold: largest body vertex jump per frame still simulated, m.
    pub teleport_threshold: f32,
    /// Speed limit: largest body centroid motion per frame the network sees, m.
    pub speed_limit: f32,
    /// Collision projection margin, m.
    pub projection_margin: f32,
    /// Solver refinement iterations per step.
    pub refine_iterations: u32,
    /// 0: the network steps; N: the solver step mode, N L-BFGS iterations per step.
    pub solver_iterations: u32,
    /// With `solver_iterations`: each step's solve also ends within this many µs (0: no budget).
    pub solver_budget_us: u32,
}

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

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers and floats.
unsafe impl Extensible for hood_sim_config {
    const NAME: &'static str = "hood_sim_config";
    // Version 0.2.0 ended before `solver_budget_us`.
    const MIN_SIZE: usize = std::mem::offset_of!(hood_sim_config, solver_budget_us);
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers and raw pointers.
unsafe impl Extensible for hood_body_desc {
    const NAME: &'static str = "hood_body_desc";
}

/// One task of a step (`extern "C"` is cdecl on 32-bit Windows, as `HOOD_CALL` declares it).
pub type hood_task_fn = Option<unsafe extern "C" fn(ctx: *mut c_void, index: u32)>;

/// An engine's job system (see the header for the contract of `run`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct hood_executor {
    /// `sizeof(hood_executor)` in the caller's header (see its Conventions).
    pub struct_size: u32,
    /// Passed back to `run`.
    pub user: *mut c_void,
    /// Tasks worth splitting into (0 counts as 1).
    pub parallelism: u32,
    /// Runs `task(ctx, i)` for every `i < n_tasks`.
    pub run: Option<unsafe extern "C" fn(user: *mut c_void, n_tasks: u32, task: hood_task_fn, ctx: *mut c_void)>,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers, a raw pointer and an optional
// function pointer (any bits are a valid `Option<fn>`; calling it is the caller's contract).
unsafe impl Extensible for hood_executor {
    const NAME: &'static str = "hood_executor";
}

/// A sim handle: a slot of `SIMS` (see the `slots` module), checked and claimed without a lock.
pub type hood_sim = slots::Slot<SimHandle>;

/// Live sims: the step and every other call on a sim take no lock (see [`slots`]).
static SIMS: slots::Slots<SimHandle> = slots::Slots::new();

/// A simulation borrowing its model, held by a [`hood_sim`] slot.
pub struct SimHandle {
    /// Borrows `*model`; `'static` stands for "while registered in `model.sims`", which
    /// `hood_model_free` enforces.
    sim: ManuallyDrop<Sim<'static>>,
    model: *const hood_model,
}

// SAFETY: the model pointer is only used to release the sim's count in it (an atomic), from
// whichever thread drops the sim; the model itself is shared read-only (see the header).
unsafe impl Send for SimHandle {}
// SAFETY: shared access only reads the sim (`Sim` is `Sync`) and never the model pointer.
unsafe impl Sync for SimHandle {}

impl Drop for SimHandle {
    fn drop(&mut self) {
        // SAFETY: dropped once, here, and never used afterwards.
        unsafe { ManuallyDrop::drop(&mut self.sim) };
        // Only now may the model go.
        // SAFETY: the model outlives every sim counted in it, and this sim is still counted.
        unsafe { &*self.model }.sims.fetch_sub(1, Ordering::SeqCst);
    }
}

/// The library's defaults, with `struct_size` this library's `sizeof(hood_sim_config)`.
fn default_config() -> hood_sim_config {
    let d = SimConfig::default();
    let s = Sleeping::default();
    let flag = |on: bool, f: u32| if on { f } else { 0 };
    let effects = flag(d.body_collision, HOOD_EFFECT_BODY_COLLISION)
        | flag(d.pinning, HOOD_EFFECT_PINNING)
        | flag(d.normals, HOOD_EFFECT_NORMALS)
        | flag(d.sleeping.is_some(), HOOD_EFFECT_SLEEPING)
        | flag(d.startup, HOOD_EFFECT_STARTUP)
        | flag(d.teleport.is_some(), HOOD_EFFECT_AUTO_TELEPORT)
        | flag(d.speed_limit.is_some(), HOOD_EFFECT_SPEED_LIMIT)
        | flag(d.projection.is_some(), HOOD_EFFECT_COLLISION_PROJECTION)
        | flag(d.refine.is_some(), HOOD_EFFECT_REFINE);
    hood_sim_config {
        struct_size: struct_size::<hood_sim_config>(),
        effects,
        precision: HOOD_PRECISION_F32,
        threads: d.threads as u32,
        sleep_frames: s.frames,
        sleep_threshold: s.threshold,
        teleport_threshold: d.teleport.unwrap_or(hood::sim::DEFAULT_TELEPORT),
        speed_limit: d.speed_limit.unwrap_or(hood::sim::DEFAULT_SPEED_LIMIT),
        projection_margin: d.projection.unwrap_or(hood::sim::DEFAULT_PROJECTION_MARGIN),
        refine_iterations: d.refine.unwrap_or(hood::sim::DEFAULT_REFINE_ITERATIONS),
        solver_budget_us: match d.step {
            StepMode::SolverBudget { micros, .. } => micros,
            _ => 0,
        },
        solver_iterations: match d.step {
            StepMode::Network => 0,
            StepMode::Solver { iterations } | StepMode::SolverBudget { max_iterations: iterations, .. } => iterations,
        },
    }
}

/// The defaults, with `struct_size` set to this library's `sizeof(hood_sim_config)`.
///
/// # Safety
/// `out` is NULL (ignored) or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_config_default(out: *mut hood_sim_config) {
    // No status to return: a (never expected) panic just leaves `out` unwritten.
    let _ = guard(|| {
        require(out, "out")?;
        // SAFETY: non-null; writable by the caller's promise.
        unsafe { write_out(out, default_config()) };
        Ok(())
    });
}

/// The defaults into a caller's config of `struct_size` bytes (see the header): the fields this
/// library knows, then zeros up to `struct_size`, and `struct_size` itself.
///
/// # Safety
/// `out` is NULL or points to `struct_size` writable bytes.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_config_init(out: *mut hood_sim_config, struct_size: usize) -> hood_status {
    guard(|| {
        require(out, "out")?;
        aligned(out, "out")?;
        if let Some(why) = size_problem::<hood_sim_config>(struct_size) {
            return Err(Failure::StructSize(format!(
                "hood_sim_config_init: struct_size {struct_size} is {why}; sizeof(hood_sim_config) is {} in this library",
                size_of::<hood_sim_config>()
            )));
        }
        // SAFETY: `struct_size` writable bytes (caller), aligned, checked above.
        unsafe { write_sized(out, default_config(), struct_size) };
        Ok(())
    })
}

fn sim_config(c: &hood_sim_config) -> Result<SimConfig> {
    if c.effects & !ALL_EFFECTS != 0 {
        return Err(Error::OutOfRange { what: "config effects (unknown flag)", index: c.effects as usize }.into());
    }
    let precision = match c.precision {
        HOOD_PRECISION_F32 => Precision::F32,
        HOOD_PRECISION_BF16 => Precision::Bf16,
        p => return Err(Error::OutOfRange { what: "config precision", index: p as usize }.into()),
    };
    let sleeping = if c.effects & HOOD_EFFECT_SLEEPING != 0 {
        if !(c.sleep_threshold.is_finite() && c.sleep_threshold >= 0.0) {
            return Err(Error::OutOfRange { what: "config sleep threshold", index: 0 }.into());
        }
        Some(Sleeping { threshold: c.sleep_threshold, frames: c.sleep_frames })
    } else {
        None
    };
    // A distance of an effect that is on: finite and positive.
    let distance = |flag: u32, value: f32, what: &'static str| -> Result<Option<f32>> {
        if c.effects & flag == 0 {
            return Ok(None);
        }
        if !(value.is_finite() && value > 0.0) {
            return Err(Error::OutOfRange { what, index: 0 }.into());
        }
        Ok(Some(value))
    };
    let teleport = distance(HOOD_EFFECT_AUTO_TELEPORT, c.teleport_threshold, "config teleport threshold")?;
    let speed_limit = distance(HOOD_EFFECT_SPEED_LIMIT, c.speed_limit, "config speed limit")?;
    // The margin's range is checked by the sim (0 <= margin < hood::sim::PROJECTION_REACH).
    let projection = (c.effects & HOOD_EFFECT_COLLISION_PROJECTION != 0).then_some(c.projection_margin);
    // The count's range is checked by the sim (1 ..= hood::sim::MAX_REFINE_ITERATIONS).
    let refine = (c.effects & HOOD_EFFECT_REFINE != 0).then_some(c.refine_iterations);
    // Likewise (and the sim refuses it beside HOOD_EFFECT_REFINE).
    let step = match (c.solver_iterations, c.solver_budget_us) {
        (0, 0) => StepMode::Network,
        (0, _) => {
            return Err(Error::UnsupportedEffect { effect: "a solver time budget without solver_iterations" }.into())
        }
        (iterations, 0) => StepMode::Solver { iterations },
        (max_iterations, micros) => StepMode::SolverBudget { micros, max_iterations },
    };
    Ok(SimConfig {
        step,
        teleport,
        speed_limit,
        projection,
        refine,
        body_collision: c.effects & HOOD_EFFECT_BODY_COLLISION != 0,
        pinning: c.effects & HOOD_EFFECT_PINNING != 0,
        normals: c.effects & HOOD_EFFECT_NORMALS != 0,
        sleeping,
        precision,
        startup: c.effects & HOOD_EFFECT_STARTUP != 0,
        tier: None,
        threads: threads(c.threads)?,
    })
}

/// The pool size for `config.threads`: a garbage count (beyond `hood::sim::MAX_THREADS`) is
/// refused; more threads than the machine's cores are capped at the cores, with a warning.
fn threads(asked: u32) -> Result<usize> {
    let asked = asked as usize;
    if asked > hood::sim::MAX_THREADS {
        return Err(Error::OutOfRange { what: "config threads (at most 256)", index: asked }.into());
    }
    let threads = hood::limits::cap_threads(asked);
    if threads < asked {
        log::log(
            HOOD_LOG_WARNING,
            &format!("config threads {asked} capped at the machine's {threads} (more would only wait for each other)"),
        );
    }
    Ok(threads)
}

/// One sim's share of a model's count of live sims, released on drop unless forgotten.
struct SimCount<'a>(&'a AtomicUsize);

impl Drop for SimCount<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Reads a body descriptor: the struct as given, the mesh (with its omitted flags) and the
/// first-frame positions.
///
/// # Safety
/// `body` is NULL (refused) or holds the `struct_size` bytes it states, and its arrays hold the
/// documented counts, unchanged during the call.
unsafe fn read_body<'a>(body: *const hood_body_desc) -> Result<(hood_body_desc, BodyMesh, &'a [[f32; 3]])> {
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

/// Creates a sim (see the header).
///
/// # Safety
/// Handles are NULL or pointers from this library (checked); `body` and `config` are NULL or
/// hold the `struct_size` bytes they state; `body`'s arrays hold the documented counts; `out` is
/// NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_new(
    model: *const hood_model,
    garment: *const hood_garment,
    body: *const hood_body_desc,
    config: *const hood_sim_config,
    out: *mut *mut hood_sim,
) -> hood_status {
    guard(|| {
        require(out, "out")?;
        check_live(garment, Kind::Garment, "garment")?;
        let cfg = if config.is_null() {
            SimConfig::default()
        } else {
            // SAFETY: non-null; `struct_size` readable bytes (caller).
            sim_config(&unsafe { read_struct(config, "config")? })?
        };
        // SAFETY: a live garment handle (checked above).
        let garment = &unsafe { &*garment }.garment;
        let body_parts = if body.is_null() {
            None
        } else {
            // SAFETY: the caller's promise.
            let (_, mesh, pos) = unsafe { read_body(body)? };
            Some((mesh, pos))
        };
        // Count the sim in the model under the registry lock, so that `hood_model_free` on
        // another thread sees it (or the model is already gone and this fails).
        {
            let reg = live();
            if model.is_null() {
                return Err(Failure::Null("model"));
            }
            if reg.get(&(model as usize)) != Some(&Kind::Model) {
                return Err(Failure::Handle("model"));
            }
            // SAFETY: a live model handle.
            unsafe { &*model }.sims.fetch_add(1, Ordering::SeqCst);
        }
        // Released on every way out but success (an error, or a panic caught by `guard`), so
        // that a failed creation never leaves the model "in use".
        // SAFETY: the model is live (our count holds it).
        let count = SimCount(unsafe { &(*model).sims });
        // SAFETY: the model is live and cannot be freed while its count includes this sim; the
        // count is released when the sim is dropped (or by `count` on failure), so the
        // `'static` borrow never outlives the model.
        let m: &'static Model<'static> = unsafe { &(*model).model };
        let bd = body_parts.as_ref().map(|(mesh, pos)| BodyDesc { mesh, positions: pos });
        match Sim::new(m, garment, bd, cfg) {
            Ok(sim) => {
                if let Some(b) = sim.body_survey().filter(|b| b.too_coarse_for(hood::sim::BODY_EDGE_RADIUS)) {
                    log::log(
                        HOOD_LOG_WARNING,
                        &format!(
                            "the body mesh is too coarse for the {} m body-edge radius: its median edge is {:.3} m \
                             (at most {:.3} m), so unpinned cloth may fall through between its vertices; use a finer body",
                            hood::sim::BODY_EDGE_RADIUS,
                            b.median_edge,
                            3f32.sqrt() * hood::sim::BODY_EDGE_RADIUS
                        ),
                    );
                }
                // The sim holds the count from here on (released when it is dropped).
                std::mem::forget(count);
                let handle = SimHandle { sim: ManuallyDrop::new(sim), model };
                // On failure the handle is dropped, releasing the model's count.
                let h = insert_slot(&SIMS, handle, "live sims")?;
                // SAFETY: `out` checked non-null.
                unsafe { write_out(out, h) };
                Ok(())
            }
            Err(e) => Err(e.into()),
        }
    })
}

/// Frees a sim; [`HOOD_ERR_BUSY`] (freeing nothing) while a call on another thread uses it.
///
/// # Safety
/// `sim` is NULL or a handle (checked against the sim slots).
#[no_mangle]
pub unsafe extern "C" fn hood_sim_free(sim: *mut hood_sim) -> hood_status {
    guard(|| free_slot(&SIMS, sim, "sim"))
}

/// Makes `value` live in a slot of `slots`.
fn insert_slot<T>(slots: &slots::Slots<T>, value: T, what: &'static str) -> Result<*mut slots::Slot<T>> {
    let capacity = slots::CAPACITY;
    slots.insert(Box::new(value)).ok_or(Error::CapacityExceeded { what, capacity, needed: capacity + 1 }.into())
}

/// Frees the value of the slot at `p` (NULL: nothing to do); busy while a call holds it.
fn free_slot<T>(slots: &slots::Slots<T>, p: *const slots::Slot<T>, what: &'static str) -> Result<()> {
    if p.is_null() {
        return Ok(());
    }
    // Dropped here, outside the slot allocator's lock.
    drop(slots.remove(p).map_err(|e| claim_failure(e, what))?);
    Ok(())
}

fn claim_failure(e: slots::ClaimError, what: &'static str) -> Failure {
    match e {
        slots::ClaimError::NotLive => Failure::Handle(what),
        slots::ClaimError::Busy => Failure::Busy(what),
    }
}

/// A call's claim on a live sim: shared (reads) or exclusive (changes), released on drop.
type SimAccess = slots::Claim<'static, SimHandle>;

/// Checks and claims `sim` (exclusive: no other call may be in progress; shared: no exclusive
/// one). Takes no lock.
fn access(sim: *const hood_sim, exclusive: bool) -> Result<SimAccess> {
    require(sim, "sim")?;
    SIMS.claim(sim, exclusive).map_err(|e| claim_failure(e, "sim"))
}

/// Shared access for a call that reads the sim.
fn sim_ref(sim: *const hood_sim) -> Result<SimRead> {
    Ok(SimRead(access(sim, false)?))
}

/// Exclusive access for a call that changes the sim.
fn sim_mut(sim: *mut hood_sim) -> Result<SimWrite> {
    Ok(SimWrite(access(sim, true)?))
}

/// Shared access: derefs to `&SimHandle` only.
struct SimRead(SimAccess);

/// Exclusive access: derefs to `&mut SimHandle`.
struct SimWrite(SimAccess);

impl std::ops::Deref for SimRead {
    type Target = SimHandle;
    fn deref(&self) -> &SimHandle {
        self.0.get()
    }
}

impl std::ops::Deref for SimWrite {
    type Target = SimHandle;
    fn deref(&self) -> &SimHandle {
        self.0.get()
    }
}

impl std::ops::DerefMut for SimWrite {
    fn deref_mut(&mut self) -> &mut SimHandle {
        self.0.get_mut().unwrap_or_else(|| unreachable!("a write claim is exclusive"))
    }
}

/// Garment vertex count.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_vertex_count(sim: *const hood_sim, out: *mut usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        // SAFETY: `out` non-null.
        unsafe { write_out(out, s.sim.garment().n_vertices()) };
        Ok(())
    })
}

/// The last network step's solver refinement (see the header).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct hood_refinement {
    /// `sizeof(hood_refinement)` in the caller's header, set before the call.
    pub struct_size: u32,
    /// Accepted L-BFGS iterations.
    pub iterations: u32,
    /// Objective at the network's prediction, J.
    pub energy_before: f32,
    /// Objective after the refinement, J.
    pub energy_after: f32,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers and floats.
unsafe impl Extensible for hood_refinement {
    const NAME: &'static str = "hood_refinement";
}

/// The last network step's solver refinement (all zero before the first one).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or a `hood_refinement` of the
/// `struct_size` it states.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_last_refinement(sim: *const hood_sim, out: *mut hood_refinement) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        if s.sim.config().refine.is_none() && s.sim.config().step == StepMode::Network {
            return Err(Error::UnsupportedEffect {
                effect: "refinement (HOOD_EFFECT_REFINE is off and the solver step mode is not on)",
            }
            .into());
        }
        let r = s.sim.last_refinement().map_or(hood_refinement::default(), |r| hood_refinement {
            struct_size: 0,
            iterations: r.iterations as u32,
            energy_before: r.f_start as f32,
            energy_after: r.f as f32,
        });
        // SAFETY: `out` is a `hood_refinement` of its `struct_size` (caller).
        unsafe { write_extensible(out, r, "out") }
    })
}

/// Body vertex count expected per step (0 without a body).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_body_vertex_count(sim: *const hood_sim, out: *mut usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        // SAFETY: `out` non-null.
        unsafe { write_out(out, s.sim.state().body_pos.len()) };
        Ok(())
    })
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

/// What the last successful step did, as `HOOD_STEP_*` flags (see the header; teleports, resets
/// and loaded states report as [`Sim::last_effects`] does).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `flags` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_last_effects(sim: *const hood_sim, flags: *mut u32) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(flags, "flags")?;
        let e = s.sim.last_effects();
        let flag = |on: bool, f: u32| if on { f } else { 0 };
        let v = flag(e.teleported, HOOD_STEP_TELEPORTED)
            | flag(e.slept, HOOD_STEP_SLEPT)
            | flag(e.startup, HOOD_STEP_STARTUP)
            | flag(e.carried, HOOD_STEP_SPEED_LIMITED)
            | flag(e.refined, HOOD_STEP_REFINED)
            | flag(e.projected, HOOD_STEP_PROJECTED);
        // SAFETY: `flags` non-null.
        unsafe { write_out(flags, v) };
        Ok(())
    })
}

/// Advances one frame (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); arrays hold the stated counts; `garment_out` does not
/// overlap `body_next`.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_step(
    sim: *mut hood_sim,
    body_next: *const f32,
    n_body_vertices: usize,
    garment_out: *mut f32,
    n_garment_vertices: usize,
) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        expect_len("body vertices", s.sim.state().body_pos.len(), n_body_vertices)?;
        expect_len("garment output vertices", s.sim.garment().n_vertices(), n_garment_vertices)?;
        require(garment_out, "garment_out")?;
        let (input, output) = (body_next as *const [f32; 3], garment_out as *const [f32; 3]);
        disjoint(input, n_body_vertices, output, n_garment_vertices, "garment_out")?;
        // SAFETY: counts are the caller's promise.
        let body = unsafe { points(body_next, n_body_vertices, "body_next")? };
        // SAFETY: as above.
        let out = unsafe { points_mut(garment_out, n_garment_vertices, "garment_out")? };
        let pos = s.sim.step(body)?;
        out.copy_from_slice(pos);
        Ok(())
    })
}

fn copy_out(src: &[[f32; 3]], out: *mut f32, n: usize, what: &'static str) -> Result<()> {
    expect_len(what, src.len(), n)?;
    require(out, "out")?;
    // SAFETY: `out` holds 3n floats (caller).
    unsafe { points_mut(out, n, "out")? }.copy_from_slice(src);
    Ok(())
}

/// Current garment positions.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` holds `3 * n_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_positions(sim: *const hood_sim, out: *mut f32, n_vertices: usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        copy_out(s.sim.positions(), out, n_vertices, "position output vertices")
    })
}

/// Current garment velocities, m/frame.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` holds `3 * n_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_velocities(sim: *const hood_sim, out: *mut f32, n_vertices: usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        copy_out(&s.sim.state().velocity, out, n_vertices, "velocity output vertices")
    })
}

/// Vertex normals of the current positions (needs `HOOD_EFFECT_NORMALS`).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` holds `3 * n_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_normals(sim: *const hood_sim, out: *mut f32, n_vertices: usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        if !s.sim.config().normals {
            return Err(Error::UnsupportedEffect { effect: "normals (HOOD_EFFECT_NORMALS is off)" }.into());
        }
        copy_out(s.sim.normals(), out, n_vertices, "normal output vertices")
    })
}

/// Sets the pin targets for the next frame.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `targets` holds `3 * n_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_set_pin_targets(
    sim: *mut hood_sim,
    targets: *const f32,
    n_vertices: usize,
) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        expect_len("pin targets", s.sim.garment().n_vertices(), n_vertices)?;
        require(targets, "targets")?;
        // SAFETY: count is the caller's promise.
        let t = unsafe { points(targets, n_vertices, "targets")? };
        s.sim.set_pin_targets(t)?;
        Ok(())
    })
}

/// Restarts from given positions with zero velocity (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); arrays hold the stated counts.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_reset(
    sim: *mut hood_sim,
    positions: *const f32,
    n_vertices: usize,
    body_positions: *const f32,
    n_body_vertices: usize,
) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        let n = s.sim.garment().n_vertices();
        expect_len("reset positions", n, n_vertices)?;
        require(positions, "positions")?;
        // SAFETY: counts are the caller's promise.
        let pos = unsafe { points(positions, n_vertices, "positions")? };
        let old = s.sim.state();
        let body = if body_positions.is_null() && n_body_vertices == 0 {
            old.body_pos.clone()
        } else {
            expect_len("reset body vertices", old.body_pos.len(), n_body_vertices)?;
            // SAFETY: as above.
            unsafe { points(body_positions, n_body_vertices, "body_positions")? }.to_vec()
        };
        let state = SimState {
            pos: pos.to_vec(),
            velocity: vec![[0.0; 3]; n],
            body_prev: body.clone(),
            body_pos: body,
            started: !s.sim.config().startup,
        };
        s.sim.set_state(&state)?;
        // Pins hold where the garment was placed (always finite: `set_state` checked them).
        s.sim.set_pin_targets(pos)?;
        Ok(())
    })
}

/// Pushes a garment's unpinned vertices out of the body at its first frame, in place (see the
/// header): [`hood::scene::push_out_of`] on the caller's arrays.
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
        let count = hood::scene::push_out_of(&mesh, body_pos, &mut x, &pins)?;
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

/// Bytes of the sim's saved state (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_state_size(sim: *const hood_sim, out: *mut usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        // SAFETY: `out` non-null.
        unsafe { write_out(out, s.sim.saved_state_len()) };
        Ok(())
    })
}

/// Saves the sim's whole state into `out` (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` holds `len` writable bytes.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_save_state(sim: *const hood_sim, out: *mut u8, len: usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        expect_len("saved state buffer", s.sim.saved_state_len(), len)?;
        // SAFETY: `len` writable bytes (caller).
        let buf = unsafe { slice_mut(out, len, "out")? };
        s.sim.save_state(buf)?;
        Ok(())
    })
}

/// Restores a saved state (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `bytes` holds `len` readable bytes.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_load_state(sim: *mut hood_sim, bytes: *const u8, len: usize) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        require(bytes, "bytes")?;
        // SAFETY: `len` readable bytes (caller).
        let b = unsafe { slice(bytes, len, "bytes")? };
        s.sim.load_state(b)?;
        Ok(())
    })
}

fn check_rotation(r: &[f32; 9]) -> Result<()> {
    if let Some(i) = r.iter().position(|v| !v.is_finite()) {
        return Err(Error::NonFinite { what: "rotation entry", index: i }.into());
    }
    // R R^T = I within 1e-3, and det R = +1 (no reflection).
    for i in 0..3 {
        for j in 0..3 {
            let d: f32 = (0..3).map(|k| r[3 * i + k] * r[3 * j + k]).sum();
            let want = if i == j { 1.0 } else { 0.0 };
            if (d - want).abs() > 1e-3 {
                return Err(Error::OutOfRange { what: "rotation (not orthonormal)", index: 3 * i + j }.into());
            }
        }
    }
    let det =
        r[0] * (r[4] * r[8] - r[5] * r[7]) - r[1] * (r[3] * r[8] - r[5] * r[6]) + r[2] * (r[3] * r[7] - r[4] * r[6]);
    if det < 0.0 {
        return Err(Error::OutOfRange { what: "rotation (a reflection, determinant -1)", index: 0 }.into());
    }
    Ok(())
}

/// Moves the garment rigidly, `p -> R p + t`, `v -> R v`, and puts the body at rest (see the
/// header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `rotation` is NULL or 9 floats; `translation` is NULL
/// or 3 floats; `body_now` is NULL or holds `3 * n_body_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_teleport(
    sim: *mut hood_sim,
    rotation: *const f32,
    translation: *const f32,
    body_now: *const f32,
    n_body_vertices: usize,
) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        let r: [f32; 9] = if rotation.is_null() {
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        } else {
            // SAFETY: 9 readable floats (caller).
            unsafe { slice(rotation, 9, "rotation")? }.try_into().unwrap_or([0.0; 9])
        };
        let t: [f32; 3] = if translation.is_null() {
            [0.0; 3]
        } else {
            // SAFETY: 3 readable floats (caller).
            (unsafe { points(translation, 1, "translation")? })[0]
        };
        check_rotation(&r)?;
        if let Some(i) = t.iter().position(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: "translation entry", index: i }.into());
        }
        // Row-major in, column-major `Mat3`: transpose.
        let rotation = Quat::from_mat3(&Mat3::from_cols_array(&r).transpose()).normalize();
        let motion = RigidMotion { rotation, translation: Vec3::from_array(t) };
        let body: Vec<[f32; 3]> = if body_now.is_null() && n_body_vertices == 0 {
            s.sim.state().body_pos.iter().map(|p| motion.apply(*p)).collect()
        } else {
            expect_len("teleport body vertices", s.sim.state().body_pos.len(), n_body_vertices)?;
            require(body_now, "body_now")?;
            // SAFETY: count is the caller's promise.
            unsafe { points(body_now, n_body_vertices, "body_now")? }.to_vec()
        };
        s.sim.teleport(&motion, &body)?;
        Ok(())
    })
}

// ---- Fixed-step driver ---------------------------------------------------------------------------

/// A driver handle: a slot of `DRIVERS`, checked and claimed without a lock like a sim's.
pub type hood_driver = slots::Slot<DriverHandle>;

/// Live drivers (see [`slots`]).
static DRIVERS: slots::Slots<DriverHandle> = slots::Slots::new();

/// The fixed-step clock of one sim, which it names by handle (claimed for each update).
pub struct DriverHandle {
    sim: *mut hood_sim,
    clock: Interpolator,
}

// SAFETY: the sim pointer is only a handle, checked and claimed on every use.
unsafe impl Send for DriverHandle {}
// SAFETY: as above; shared access only reads the step count.
unsafe impl Sync for DriverHandle {}

/// Makes a fixed-step driver of `sim` (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_driver_new(sim: *mut hood_sim, out: *mut *mut hood_driver) -> hood_status {
    guard(|| {
        require(out, "out")?;
        let s = sim_ref(sim)?;
        let handle = DriverHandle { sim, clock: Interpolator::new(&s.sim) };
        let h = insert_slot(&DRIVERS, handle, "live drivers")?;
        // SAFETY: `out` checked non-null.
        unsafe { write_out(out, h) };
        Ok(())
    })
}

/// Frees a driver (its sim stays).
///
/// # Safety
/// `driver` is NULL or a handle (checked against the driver slots).
#[no_mangle]
pub unsafe extern "C" fn hood_driver_free(driver: *mut hood_driver) -> hood_status {
    guard(|| free_slot(&DRIVERS, driver, "driver"))
}

/// Advances engine time by `dt` seconds and writes the interpolated garment (see the header).
///
/// # Safety
/// `driver` is NULL or a handle (checked); arrays hold the stated counts; `garment_out` does not
/// overlap `body_now`.
#[no_mangle]
pub unsafe extern "C" fn hood_driver_update(
    driver: *mut hood_driver,
    dt: f32,
    body_now: *const f32,
    n_body_vertices: usize,
    garment_out: *mut f32,
    n_garment_vertices: usize,
) -> hood_status {
    guard(|| {
        require(driver, "driver")?;
        let mut d = DRIVERS.claim(driver, true).map_err(|e| claim_failure(e, "driver"))?;
        let d = d.get_mut().unwrap_or_else(|| unreachable!("a write claim is exclusive"));
        let mut s = sim_mut(d.sim)?;
        require(garment_out, "garment_out")?;
        let (input, output) = (body_now as *const [f32; 3], garment_out as *const [f32; 3]);
        disjoint(input, n_body_vertices, output, n_garment_vertices, "garment_out")?;
        expect_len("garment output vertices", s.sim.garment().n_vertices(), n_garment_vertices)?;
        // SAFETY: counts are the caller's promise.
        let body = unsafe { points(body_now, n_body_vertices, "body_now")? };
        // SAFETY: as above.
        let out = unsafe { points_mut(garment_out, n_garment_vertices, "garment_out")? };
        let pos = d.clock.update(&mut s.sim, dt, body)?;
        out.copy_from_slice(pos);
        Ok(())
    })
}

/// Model steps a driver has taken.
///
/// # Safety
/// `driver` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_driver_model_steps(driver: *const hood_driver, out: *mut u64) -> hood_status {
    guard(|| {
        require(driver, "driver")?;
        let d = DRIVERS.claim(driver, false).map_err(|e| claim_failure(e, "driver"))?;
        require(out, "out")?;
        // SAFETY: `out` non-null.
        unsafe { write_out(out, d.get().clock.model_steps()) };
        Ok(())
    })
}

/// Adapts a C job system to [`Executor`].
struct CExecutor {
    raw: hood_executor,
    run: unsafe extern "C" fn(*mut c_void, u32, hood_task_fn, *mut c_void),
}

// SAFETY: the header makes `user` and `run` usable from the thread that steps the sim (the
// caller's promise); the library itself calls `run` only from that thread.
unsafe impl Send for CExecutor {}
// SAFETY: as above; `CExecutor` has no interior mutability of its own.
unsafe impl Sync for CExecutor {}

/// Task indices a C executor may be handed at once: each has a claim bit, so that an index run
/// twice is refused instead of aliasing a task's buffers (larger jobs run serially).
const C_EXECUTOR_MAX_TASKS: usize = 4096;

struct TaskCtx<'a> {
    task: &'a (dyn Fn(usize) + Sync),
    n: usize,
    calls: AtomicUsize,
    /// One bit per task index, set by the first call of that index.
    claimed: [AtomicU64; C_EXECUTOR_MAX_TASKS / 64],
    bad: AtomicBool,
    panicked: AtomicBool,
}

unsafe extern "C" fn run_task(ctx: *mut c_void, index: u32) {
    if ctx.is_null() {
        return;
    }
    // SAFETY: `ctx` is the `TaskCtx` that `CExecutor::run` passed to `run`, alive until `run`
    // returns (the executor contract: all tasks finish before `run` returns).
    let c = unsafe { &*(ctx as *const TaskCtx<'_>) };
    let i = index as usize;
    if i >= c.n {
        c.bad.store(true, Ordering::SeqCst);
        return;
    }
    // An index run a second time would alias the first run's buffers: refuse it.
    let bit = 1u64 << (i % 64);
    if c.claimed[i / 64].fetch_or(bit, Ordering::AcqRel) & bit != 0 {
        c.bad.store(true, Ordering::SeqCst);
        return;
    }
    c.calls.fetch_add(1, Ordering::SeqCst);
    let _inside = log::Inside::enter();
    // No unwinding through the C job system: remember the panic and re-raise it after `run`.
    if let Err(payload) = catch_unwind(AssertUnwindSafe(|| (c.task)(i))) {
        let _ = catch_unwind(AssertUnwindSafe(|| {
            log::log(HOOD_LOG_ERROR, &format!("a step task panicked: {}", panic_message(&*payload)))
        }));
        c.panicked.store(true, Ordering::SeqCst);
    }
}

// SAFETY: whatever the C `run` does, `run_task` runs each index in `0..n` at most once (claim
// bits) and `run` returns only after the C `run` has (the header's contract: every task has
// finished by then); a missing or repeated index is reported as a failed step.
unsafe impl Executor for CExecutor {
    fn parallelism(&self) -> usize {
        self.raw.parallelism.max(1) as usize
    }

    fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
        if n == 0 {
            return;
        }
        if n > C_EXECUTOR_MAX_TASKS {
            (0..n).for_each(task);
            return;
        }
        let n32 = n as u32;
        let ctx = TaskCtx {
            task,
            n,
            calls: AtomicUsize::new(0),
            claimed: std::array::from_fn(|_| AtomicU64::new(0)),
            bad: AtomicBool::new(false),
            panicked: AtomicBool::new(false),
        };
        // SAFETY: a C function supplied through `hood_sim_set_executor`, called as documented;
        // `ctx` outlives the call.
        unsafe { (self.run)(self.raw.user, n32, Some(run_task), &ctx as *const TaskCtx<'_> as *mut c_void) };
        // Panics here are caught by `guard` at the export.
        assert!(!ctx.panicked.load(Ordering::SeqCst), "a step task panicked");
        let calls = ctx.calls.load(Ordering::SeqCst);
        assert!(
            !ctx.bad.load(Ordering::SeqCst) && calls == n,
            "the executor did not run every task exactly once ({calls} calls for {n} tasks)"
        );
    }
}

/// Plugs in (or with NULL removes) an engine executor.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `executor` is NULL or holds the `struct_size` bytes it
/// states and keeps the contract in the header.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_set_executor(sim: *mut hood_sim, executor: *const hood_executor) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        let exec: Box<dyn Executor> = if executor.is_null() {
            let threads = s.sim.config().threads;
            if threads > 1 {
                Box::new(ThreadPool::new(threads))
            } else {
                Box::new(Serial)
            }
        } else {
            // SAFETY: non-null; `struct_size` readable bytes (caller).
            let raw = unsafe { read_struct(executor, "executor")? };
            let run = raw.run.ok_or(Failure::Null("executor run"))?;
            Box::new(CExecutor { raw, run })
        };
        s.sim.set_executor(exec);
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ptr::{null, null_mut};

    /// A sim of a random model (the bytes are leaked: they outlive the model).
    fn small_sim() -> *mut hood_sim {
        let spec = hood::model::ModelSpec::hood(8);
        let mut p = hood::model::Params::init(&spec, 3).unwrap();
        p.normalisers = hood::model::Normalisers::unit_scale(3);
        let file = hood::model::write_model(&p, false, &[]).unwrap();
        let bytes: &'static hood::model::ModelBytes = Box::leak(Box::new(hood::model::ModelBytes::new(&file)));
        let (rest, faces) = hood::mesh::shapes::grid(3, 3, 0.3, 0.3, 0.0);
        let (mut model, mut garment, mut sim) = (null_mut(), null_mut(), null_mut());
        // SAFETY: arrays of the stated lengths; the model bytes are leaked.
        unsafe {
            let b = bytes.as_bytes();
            assert_eq!(hood_model_load(b.as_ptr(), b.len(), &mut model), HOOD_OK);
            let (r, f) = (rest.as_ptr().cast(), faces.as_ptr().cast());
            assert_eq!(hood_garment_new(r, rest.len(), f, faces.len(), null(), 0, null(), &mut garment), HOOD_OK);
            assert_eq!(hood_sim_new(model, garment, null(), null(), &mut sim), HOOD_OK);
            assert_eq!(hood_garment_free(garment), HOOD_OK);
        }
        sim
    }

    /// A length whose byte size overflows is refused as out of range wherever the arrays lie,
    /// never mistaken for an overlap (a saturated end would overlap everything above it).
    #[test]
    fn overflowing_lengths_are_out_of_range_not_overlaps() {
        let data = [0u64; 4];
        let (low, high) = (data.as_ptr(), data[3..].as_ptr());
        for (input, output) in [(low, high), (high, low)] {
            for (a, b) in [(1, usize::MAX / 4), (usize::MAX / 4, 1)] {
                let e = disjoint(input, a, output, b, "out").unwrap_err();
                assert!(matches!(e, Failure::Hood(Error::OutOfRange { .. })), "{a} {b}");
            }
        }
        assert!(disjoint(low, 3, high, 1, "out").is_ok());
        assert!(matches!(disjoint(low, 4, high, 1, "out"), Err(Failure::Pointer("out", _))));
    }

    /// The calls on a sim, the step first, need neither the handle registry's lock nor the sim
    /// slots' allocator lock: they finish while another thread holds both.
    #[test]
    fn calls_on_a_sim_take_no_lock() {
        let sim = small_sim() as usize;
        let registry = live();
        let allocator = SIMS.hold_lock();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let sim = sim as *mut hood_sim;
            let mut out = [[0.0f32; 3]; 9];
            let mut codes = Vec::new();
            // SAFETY: a live sim; `out` holds 9 points.
            unsafe {
                for _ in 0..3 {
                    codes.push(hood_sim_step(sim, null(), 0, out.as_mut_ptr().cast(), 9));
                }
                codes.push(hood_sim_positions(sim, out.as_mut_ptr().cast(), 9));
                codes.push(hood_sim_velocities(sim, out.as_mut_ptr().cast(), 9));
            }
            let _ = tx.send(codes);
        });
        let codes = rx.recv_timeout(std::time::Duration::from_secs(60)).expect("a call on a sim waited for a lock");
        assert!(codes.iter().all(|&c| c == HOOD_OK), "{codes:?}");
        drop((registry, allocator));
        // SAFETY: a live, idle sim.
        assert_eq!(unsafe { hood_sim_free(sim as *mut hood_sim) }, HOOD_OK);
    }
}
