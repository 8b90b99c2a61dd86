//! The registry of live model and garment handles, which turns a freed, foreign or mismatched
//! handle into [`HOOD_ERR_INVALID_HANDLE`].
//!
//! [`HOOD_ERR_INVALID_HANDLE`]: crate::HOOD_ERR_INVALID_HANDLE

use crate::status::{Failure, Result};
use std::collections::BTreeMap;
use std::sync::Mutex;

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(crate) enum Kind {
    Model,
    Garment,
}

/// A registered handle: its kind, and how many calls are using it right now.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Entry {
    pub(crate) kind: Kind,
    users: usize,
}

/// Live model and garment handles by address. A handle is usable only while registered, which
/// turns use after free, double free and handles of the wrong kind into
/// [`HOOD_ERR_INVALID_HANDLE`]; and a call counts itself as a user for as long as it reads the
/// handle ([`use_live`]), so that freeing it meanwhile (from another thread, or from a callback
/// the call makes) is refused with [`HOOD_ERR_BUSY`] instead of freeing what the call reads.
/// Sims are not here: their handles are slots that calls check and claim without a lock (see
/// [`slots`]).
///
/// [`HOOD_ERR_INVALID_HANDLE`]: crate::HOOD_ERR_INVALID_HANDLE
/// [`HOOD_ERR_BUSY`]: crate::HOOD_ERR_BUSY
/// [`slots`]: crate::slots
static LIVE: Mutex<BTreeMap<usize, Entry>> = Mutex::new(BTreeMap::new());

pub(crate) fn live() -> std::sync::MutexGuard<'static, BTreeMap<usize, Entry>> {
    // The map is updated by single inserts, removes and counter changes, so a poisoned lock
    // still holds a valid map.
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

pub(crate) fn register<T>(b: Box<T>, kind: Kind) -> *mut T {
    let p = Box::into_raw(b);
    live().insert(p as usize, Entry { kind, users: 0 });
    p
}

/// A call's use of a live handle: while it exists the handle cannot be freed (the free returns
/// [`HOOD_ERR_BUSY`](crate::HOOD_ERR_BUSY)), so the pointer stays valid. Taken and dropped under
/// the registry's lock, which is not held in between.
#[must_use = "the handle is protected only while the use is held"]
pub(crate) struct Use {
    addr: usize,
}

impl Drop for Use {
    fn drop(&mut self) {
        if let Some(e) = live().get_mut(&self.addr) {
            e.users -= 1;
        }
    }
}

/// Checks that `p` is a live handle of `kind` and holds it for the caller's use.
pub(crate) fn use_live<T>(p: *const T, kind: Kind, what: &'static str) -> Result<Use> {
    if p.is_null() {
        return Err(Failure::Null(what));
    }
    match live().get_mut(&(p as usize)) {
        Some(e) if e.kind == kind => {
            e.users += 1;
            Ok(Use { addr: p as usize })
        }
        _ => Err(Failure::Handle(what)),
    }
}

/// Removes a handle from the registry (the caller then owns the box); `Ok(None)` for NULL.
/// Refused while a call uses the handle ([`use_live`]), or when `in_use` (run under the
/// registry's lock, on the live value) says it is still needed.
pub(crate) fn unregister<T>(
    p: *mut T,
    kind: Kind,
    what: &'static str,
    in_use: impl FnOnce(&T) -> Result<()>,
) -> Result<Option<Box<T>>> {
    if p.is_null() {
        return Ok(None);
    }
    let mut reg = live();
    match reg.get(&(p as usize)) {
        Some(e) if e.kind == kind && e.users > 0 => Err(Failure::Busy(what)),
        Some(e) if e.kind == kind => {
            // SAFETY: registered, so a valid `T` (see below).
            in_use(unsafe { &*p })?;
            reg.remove(&(p as usize));
            // SAFETY: registered addresses come from `Box::into_raw` of a `T` of this kind (the
            // kind was checked) and are removed exactly once, here, so the box is still owned.
            Ok(Some(unsafe { Box::from_raw(p) }))
        }
        _ => Err(Failure::Handle(what)),
    }
}
