//! The global allocator of the C libraries: the system allocator, or the engine's callbacks when
//! `hood_set_allocator` installed them before the library's first allocation (memory must be
//! freed by the allocator that gave it, so the choice is made once, before any).

use std::alloc::{GlobalAlloc, Layout, System};
use std::ffi::c_void;
use std::sync::atomic::{AtomicPtr, AtomicU8, Ordering};

/// The engine's allocation functions: `alloc(size, align, user)` (NULL on failure) and
/// `free(ptr, size, align, user)`.
#[derive(Clone, Copy)]
pub struct Hooks {
    pub alloc: AllocFn,
    pub free: FreeFn,
    pub user: *mut c_void,
}

/// The engine's `alloc`.
pub type AllocFn = unsafe extern "C-unwind" fn(usize, usize, *mut c_void) -> *mut c_void;
/// The engine's `free`.
pub type FreeFn = unsafe extern "C-unwind" fn(*mut c_void, usize, usize, *mut c_void);

/// Calls the engine's `alloc`. An allocator must not unwind: an exception thrown out of the
/// engine's function (against the header's contract) stops at this `extern "C"` boundary, which
/// aborts the process, instead of unwinding through Rust's allocator (undefined behaviour).
///
/// # Safety
/// `f` keeps the header's contract for `alloc`.
unsafe extern "C" fn call_alloc(f: AllocFn, size: usize, align: usize, user: *mut c_void) -> *mut c_void {
    // SAFETY: the caller's promise.
    unsafe { f(size, align, user) }
}

/// Calls the engine's `free`, as [`call_alloc`] calls its `alloc`.
///
/// # Safety
/// `f` keeps the header's contract for `free`, and `ptr` came from its `alloc` with this size
/// and alignment.
unsafe extern "C" fn call_free(f: FreeFn, ptr: *mut c_void, size: usize, align: usize, user: *mut c_void) {
    // SAFETY: the caller's promise.
    unsafe { f(ptr, size, align, user) }
}

/// Nothing allocated yet, no hooks.
const UNTOUCHED: u8 = 0;
/// The system allocator is in use (for good).
const SYSTEM: u8 = 1;
/// Hooks are being installed: allocations wait for [`HOOKED`].
const INSTALLING: u8 = 2;
/// The hooks are in use (for good).
const HOOKED: u8 = 3;

static STATE: AtomicU8 = AtomicU8::new(UNTOUCHED);
/// Written once, while [`INSTALLING`]; read once [`HOOKED`].
static HOOKS: AtomicPtr<Hooks> = AtomicPtr::new(std::ptr::null_mut());

/// Installs `hooks` if nothing has been allocated yet; `false` (nothing changed) otherwise.
pub fn install(hooks: Hooks) -> bool {
    if STATE.compare_exchange(UNTOUCHED, INSTALLING, Ordering::AcqRel, Ordering::Acquire).is_err() {
        return false;
    }
    // Allocated with the hooks' own `alloc` would need them installed first: this one comes from
    // the system and is never freed (the hooks stay for the life of the process).
    let layout = Layout::new::<Hooks>();
    // SAFETY: a non-zero-sized layout.
    let p = unsafe { System.alloc(layout) }.cast::<Hooks>();
    if p.is_null() {
        STATE.store(SYSTEM, Ordering::Release);
        return false;
    }
    // SAFETY: fresh, aligned memory for one `Hooks`.
    unsafe { p.write(hooks) };
    HOOKS.store(p, Ordering::Release);
    STATE.store(HOOKED, Ordering::Release);
    true
}

/// The allocator in use, choosing the system allocator at the first allocation without hooks.
fn current() -> Option<Hooks> {
    loop {
        match STATE.load(Ordering::Acquire) {
            SYSTEM => return None,
            // SAFETY: set before the state became HOOKED and never changed or freed after.
            HOOKED => return Some(unsafe { *HOOKS.load(Ordering::Acquire) }),
            INSTALLING => std::hint::spin_loop(),
            _ => {
                if STATE.compare_exchange(UNTOUCHED, SYSTEM, Ordering::AcqRel, Ordering::Acquire).is_ok() {
                    return None;
                }
            }
        }
    }
}

/// The global allocator (see the module docs).
pub struct Hooked;

// SAFETY: every block comes from, and goes back to, the allocator chosen once for the process
// (the system's or the hooks, whose contract the header states); layouts are passed through.
unsafe impl GlobalAlloc for Hooked {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        match current() {
            // SAFETY: the caller's layout, non-zero-sized (`GlobalAlloc` contract).
            None => unsafe { System.alloc(layout) },
            // SAFETY: the engine's function, called as the header documents.
            Some(h) => unsafe { call_alloc(h.alloc, layout.size(), layout.align(), h.user) }.cast(),
        }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        match current() {
            // SAFETY: `ptr` came from `System.alloc` with `layout` (the choice never changes).
            None => unsafe { System.dealloc(ptr, layout) },
            // SAFETY: `ptr` came from `h.alloc` with this size and alignment.
            Some(h) => unsafe { call_free(h.free, ptr.cast(), layout.size(), layout.align(), h.user) },
        }
    }
}
