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

/// Live model and garment handles by address. A handle is usable only while registered, which
/// turns use after free, double free and handles of the wrong kind into
/// [`HOOD_ERR_INVALID_HANDLE`]. Sims are not here: their handles are slots that calls check and
/// claim without a lock (see [`slots`]).
///
/// [`HOOD_ERR_INVALID_HANDLE`]: crate::HOOD_ERR_INVALID_HANDLE
/// [`slots`]: crate::slots
static LIVE: Mutex<BTreeMap<usize, Kind>> = Mutex::new(BTreeMap::new());

pub(crate) fn live() -> std::sync::MutexGuard<'static, BTreeMap<usize, Kind>> {
    // The map is updated by single inserts/removes, so a poisoned lock still holds a valid map.
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

pub(crate) fn register<T>(b: Box<T>, kind: Kind) -> *mut T {
    let p = Box::into_raw(b);
    live().insert(p as usize, kind);
    p
}

pub(crate) fn check_live<T>(p: *const T, kind: Kind, what: &'static str) -> Result<()> {
    if p.is_null() {
        return Err(Failure::Null(what));
    }
    match live().get(&(p as usize)) {
        Some(&k) if k == kind => Ok(()),
        _ => Err(Failure::Handle(what)),
    }
}

/// Removes a handle from the registry (the caller then owns the box); `Ok(None)` for NULL.
pub(crate) fn unregister<T>(p: *mut T, kind: Kind, what: &'static str) -> Result<Option<Box<T>>> {
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
