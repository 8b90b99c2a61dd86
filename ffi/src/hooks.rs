//! The engine's hooks into the library: its allocator (`hood_set_allocator`) and its log
//! callback (`hood_set_log_callback`).

use crate::extensible::{read_extensible, Extensible};
use crate::guard::guard;
use crate::status::{hood_status, Failure, HOOD_OK};
use crate::{alloc, log};
use hood::Error;
use std::ffi::{c_char, c_void};

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
    pub alloc: Option<unsafe extern "C-unwind" fn(size: usize, align: usize, user: *mut c_void) -> *mut c_void>,
    /// Frees a block of `alloc` with its size and alignment.
    pub free: Option<unsafe extern "C-unwind" fn(ptr: *mut c_void, size: usize, align: usize, user: *mut c_void)>,
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

/// The log callback's type (`extern "C-unwind"` is cdecl on 32-bit Windows, as `HOOD_CALL`
/// declares it; `-unwind` so that an exception thrown out of it, against the header's contract,
/// aborts the process at the export's boundary instead of being undefined behaviour).
pub type hood_log_fn = Option<unsafe extern "C-unwind" fn(level: u32, message: *const c_char, user: *mut c_void)>;

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
