//! The log callback: where the library's warnings and the messages of panics caught at the
//! boundary go. Without one, warnings go nowhere and a panic is printed by Rust's panic hook (to
//! stderr), as before the callback existed.

use std::cell::{Cell, RefCell};
use std::ffi::{c_char, c_void, CString};
use std::sync::{Mutex, Once};

/// The caller's log function: `(level, message, user)`.
pub type LogFn = unsafe extern "C-unwind" fn(u32, *const c_char, *mut c_void);

/// The callback and its `user` pointer.
#[derive(Clone, Copy)]
struct Logger {
    f: LogFn,
    user: *mut c_void,
}

// SAFETY: the header makes the callback and `user` usable from any thread that calls the library
// (the caller's promise); the library only passes `user` back.
unsafe impl Send for Logger {}

/// Taken to set the callback and to copy it before a call; never held while it runs (a callback
/// may call the library again).
static LOGGER: Mutex<Option<Logger>> = Mutex::new(None);

thread_local! {
    /// Calls of the library in progress on this thread (exports and executor tasks).
    static INSIDE: Cell<u32> = const { Cell::new(0) };
    /// Where the last panic inside the library on this thread happened, kept by the panic hook
    /// for the boundary that catches it.
    static PANIC_AT: RefCell<Option<String>> = const { RefCell::new(None) };
}

fn logger() -> Option<Logger> {
    *LOGGER.lock().unwrap_or_else(|e| e.into_inner())
}

/// Sets (or with `None` removes) the callback. The first callback installs a panic hook that
/// keeps panics inside the library off stderr while a callback is set.
pub fn set(f: Option<LogFn>, user: *mut c_void) {
    static HOOK: Once = Once::new();
    if f.is_some() {
        HOOK.call_once(|| {
            let previous = std::panic::take_hook();
            std::panic::set_hook(Box::new(move |info| {
                let ours = INSIDE.try_with(|d| d.get() > 0).unwrap_or(false)
                    || std::thread::current().name().is_some_and(|n| n.starts_with("hood-worker-"));
                if ours && logger().is_some() {
                    let at = info.location().map(|l| format!("{}:{}", l.file(), l.line()));
                    let _ = PANIC_AT.try_with(|p| *p.borrow_mut() = at);
                } else {
                    previous(info);
                }
            }));
        });
    }
    *LOGGER.lock().unwrap_or_else(|e| e.into_inner()) = f.map(|f| Logger { f, user });
}

/// Passes `message` to the callback, if one is set.
pub fn log(level: u32, message: &str) {
    if let Some(l) = logger() {
        let c = CString::new(message.replace('\0', " ")).unwrap_or_default();
        // SAFETY: a function the caller set with `hood_set_log_callback`, called as the header
        // documents; `c` outlives the call.
        unsafe { (l.f)(level, c.as_ptr(), l.user) };
    }
}

/// Where the panic just caught on this thread happened (`file:line`), if the hook saw it.
pub fn take_panic_location() -> Option<String> {
    PANIC_AT.try_with(|p| p.borrow_mut().take()).ok().flatten()
}

/// Marks this thread as inside the library for the life of the value.
pub struct Inside(());

impl Inside {
    pub fn enter() -> Inside {
        let _ = INSIDE.try_with(|d| d.set(d.get() + 1));
        Inside(())
    }
}

impl Drop for Inside {
    fn drop(&mut self) {
        let _ = INSIDE.try_with(|d| d.set(d.get().saturating_sub(1)));
    }
}
