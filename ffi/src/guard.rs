//! The guard every export runs in (a failure becomes a status code and this thread's last error
//! message, a panic [`HOOD_ERR_PANIC`]), and `hood_last_error`, which returns that message.

use crate::consts::HOOD_LOG_ERROR;
use crate::log;
use crate::status::{hood_status, Result, HOOD_ERR_PANIC, HOOD_OK};
use std::cell::RefCell;
use std::ffi::{c_char, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_last_error(msg: String) {
    let c = CString::new(msg.replace('\0', " ")).unwrap_or_default();
    // Ignore failure during thread teardown: there is nobody left to read the message.
    let _ = LAST_ERROR.try_with(|s| *s.borrow_mut() = c);
}

pub(crate) fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
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
pub(crate) fn guard(f: impl FnOnce() -> Result<()>) -> hood_status {
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

/// The message of the most recent failing call on this thread ("" if none).
#[no_mangle]
pub extern "C" fn hood_last_error() -> *const c_char {
    static EMPTY: &CStr = c"";
    catch_unwind(|| LAST_ERROR.try_with(|s| s.borrow().as_ptr()).unwrap_or(EMPTY.as_ptr())).unwrap_or(EMPTY.as_ptr())
}
