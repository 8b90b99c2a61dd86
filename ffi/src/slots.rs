//! Sim handles without a lock on the calls that use them.
//!
//! A `hood_sim *` is the address of a [`Slot`] in type-stable memory: slots are allocated in
//! segments that are never freed, so any address can be checked against them (a few range
//! comparisons) and a slot's state word read, whether the handle is live, freed or was never
//! made, without a registry lock. Each slot's state word holds a live bit and the calls in
//! progress; a call claims the slot with one compare-and-swap, so a free racing a step, or two
//! steps at once, are refused with `HOOD_ERR_BUSY` instead of racing. Only creating and
//! freeing a sim take the allocator's lock, and the sim itself is dropped outside it.
//!
//! A freed slot is reused only after [`QUARANTINE`] other slots have been freed, so a stale
//! handle is reported as invalid long after its free instead of reaching a newer sim.

use std::cell::UnsafeCell;
use std::collections::VecDeque;
use std::marker::PhantomData;
use std::sync::atomic::{AtomicPtr, AtomicU32, Ordering};
use std::sync::Mutex;

/// Set in [`Slot::state`] while the slot holds a sim.
const LIVE: u32 = 1 << 31;
/// The access part of [`Slot::state`] of one call that changes the sim (exclusive).
const WRITER: u32 = LIVE - 1;

/// Slots in segment 0; segment `k` holds `FIRST_SEGMENT << k`.
const FIRST_SEGMENT: usize = 64;
/// Segments at most (far more slots than an address space holds sims); fewer where `usize` is
/// narrower than 64 bits, so that [`CAPACITY`] fits it.
const SEGMENTS: usize = if usize::BITS >= 64 { 40 } else { usize::BITS as usize - 8 };
/// Slots in all segments: the most sims live at once.
pub const CAPACITY: usize = FIRST_SEGMENT * ((1 << SEGMENTS) - 1);
/// Freed slots kept out of use before one is reused (see the module docs).
pub const QUARANTINE: usize = 4096;

/// One sim handle's memory: the state word and the sim it holds while live.
pub struct Slot<T> {
    /// [`LIVE`] while the slot holds a value, plus the calls in progress: 0 none, [`WRITER`] one
    /// that changes it, else that many that only read it.
    state: AtomicU32,
    /// `Some` while live. Written only by the thread that creates or frees the slot's value,
    /// while no call can claim it (the live bit is clear); read under a claim.
    value: UnsafeCell<Option<Box<T>>>,
}

/// Slot memory that is never freed, and the free slots.
pub struct Slots<T> {
    segments: [AtomicPtr<Slot<T>>; SEGMENTS],
    alloc: Mutex<Alloc>,
    /// The slots own their values.
    _values: PhantomData<Box<T>>,
}

/// The allocator's state (under [`Slots::alloc`]).
struct Alloc {
    /// Segments allocated so far.
    segments: usize,
    /// Slots of the last segment handed out so far.
    used: usize,
    /// Freed slots, oldest first.
    free: VecDeque<usize>,
}

// SAFETY: a slot's value is reached only through a claim on its state word (see `Slot::value`),
// which hands `&T` to readers and `&mut T` to one writer at a time; `T: Send` lets the value be
// created, used and dropped on different threads, `T: Sync` lets readers share it.
unsafe impl<T: Send + Sync> Sync for Slots<T> {}

const fn segment_len(k: usize) -> usize {
    FIRST_SEGMENT << k
}

/// Why a slot could not be claimed.
#[derive(Debug, PartialEq, Eq)]
pub enum ClaimError {
    /// Not the address of a live slot.
    NotLive,
    /// Live, but a call on another thread holds it.
    Busy,
}

impl<T> Slots<T> {
    /// No slots yet.
    pub const fn new() -> Self {
        Slots {
            segments: [const { AtomicPtr::new(std::ptr::null_mut()) }; SEGMENTS],
            alloc: Mutex::new(Alloc { segments: 0, used: 0, free: VecDeque::new() }),
            _values: PhantomData,
        }
    }

    /// Holds the allocator's lock (tests that check which calls need it).
    #[cfg(test)]
    pub fn hold_lock(&self) -> impl Drop + '_ {
        self.lock()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Alloc> {
        // Every update of `Alloc` is a single push, pop or increment: a poisoned lock still
        // holds a consistent allocator.
        self.alloc.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The slot at address `p`, if `p` is the start of a slot of these segments. Takes no lock.
    pub fn find(&self, p: *const Slot<T>) -> Option<&Slot<T>> {
        let addr = p as usize;
        let size = size_of::<Slot<T>>();
        for (k, seg) in self.segments.iter().enumerate() {
            let base = seg.load(Ordering::Acquire);
            if base.is_null() {
                return None;
            }
            let start = base as usize;
            let offset = addr.wrapping_sub(start);
            if addr >= start && offset < segment_len(k) * size {
                // SAFETY: segments are never freed, and a slot-aligned offset inside one is a slot.
                return offset.is_multiple_of(size).then(|| unsafe { &*base.add(offset / size) });
            }
        }
        None
    }

    /// The slot of index `i` (allocated).
    fn slot(&self, i: usize) -> *mut Slot<T> {
        let (mut k, mut i) = (0, i);
        while i >= segment_len(k) {
            i -= segment_len(k);
            k += 1;
        }
        // SAFETY: `i` indexes an allocated segment (the allocator's bookkeeping).
        unsafe { self.segments[k].load(Ordering::Acquire).add(i) }
    }

    /// Stores `value` in a free slot and makes it live; `None` when every slot is taken.
    pub fn insert(&self, value: Box<T>) -> Option<*mut Slot<T>> {
        let mut a = self.lock();
        let index = if a.free.len() > QUARANTINE {
            a.free.pop_front()?
        } else {
            if a.segments == 0 || a.used == segment_len(a.segments - 1) {
                if a.segments == SEGMENTS {
                    return None;
                }
                let seg: Box<[Slot<T>]> = (0..segment_len(a.segments))
                    .map(|_| Slot { state: AtomicU32::new(0), value: UnsafeCell::new(None) })
                    .collect();
                // Never freed: handles may be checked against it at any time.
                let base = Box::leak(seg).as_mut_ptr();
                self.segments[a.segments].store(base, Ordering::Release);
                a.segments += 1;
                a.used = 0;
            }
            a.used += 1;
            (0..a.segments - 1).map(segment_len).sum::<usize>() + a.used - 1
        };
        drop(a);
        let slot = self.slot(index);
        // SAFETY: a free slot (from the free list or never used): its live bit is clear, so no
        // call can claim it, and only this thread holds its index.
        unsafe { *(*slot).value.get() = Some(value) };
        // SAFETY: as above; the release publishes the value to the claims that see the bit.
        unsafe { &*slot }.state.store(LIVE, Ordering::Release);
        Some(slot)
    }

    /// Takes the value out of the live, idle slot at `p` (the slot is no longer live and goes
    /// to the free list): [`ClaimError::Busy`] while a call holds it.
    pub fn remove(&self, p: *const Slot<T>) -> Result<Box<T>, ClaimError> {
        let slot = self.find(p).ok_or(ClaimError::NotLive)?;
        match slot.state.compare_exchange(LIVE, 0, Ordering::AcqRel, Ordering::Acquire) {
            Ok(_) => {}
            Err(s) if s & LIVE != 0 => return Err(ClaimError::Busy),
            Err(_) => return Err(ClaimError::NotLive),
        }
        // SAFETY: the live bit was cleared by this thread from an idle state, so no call holds
        // or can take a claim: the value is this thread's alone.
        let value = unsafe { (*slot.value.get()).take() };
        let index = self.index_of(slot);
        self.lock().free.push_back(index);
        value.ok_or(ClaimError::NotLive)
    }

    fn index_of(&self, slot: &Slot<T>) -> usize {
        let addr = slot as *const Slot<T> as usize;
        let mut first = 0;
        for (k, seg) in self.segments.iter().enumerate() {
            let start = seg.load(Ordering::Acquire) as usize;
            if addr >= start && addr < start + segment_len(k) * size_of::<Slot<T>>() {
                return first + (addr - start) / size_of::<Slot<T>>();
            }
            first += segment_len(k);
        }
        unreachable!("a slot found in the segments")
    }

    /// Claims the live slot at `p` for one call: exclusive (no other call in progress) or
    /// shared (no exclusive one). Takes no lock.
    pub fn claim(&self, p: *const Slot<T>, exclusive: bool) -> Result<Claim<'_, T>, ClaimError> {
        let slot = self.find(p).ok_or(ClaimError::NotLive)?;
        let r = if exclusive {
            slot.state.compare_exchange(LIVE, LIVE | WRITER, Ordering::AcqRel, Ordering::Acquire)
        } else {
            slot.state.fetch_update(Ordering::AcqRel, Ordering::Acquire, |s| {
                (s & LIVE != 0 && s & WRITER < WRITER - 1).then(|| s + 1)
            })
        };
        match r {
            Ok(_) => Ok(Claim { slot, exclusive }),
            Err(s) if s & LIVE != 0 => Err(ClaimError::Busy),
            Err(_) => Err(ClaimError::NotLive),
        }
    }
}

/// A call's claim on a live slot, released on drop.
pub struct Claim<'a, T> {
    slot: &'a Slot<T>,
    exclusive: bool,
}

impl<T> Claim<'_, T> {
    /// The value, shared.
    pub fn get(&self) -> &T {
        // SAFETY: a claimed slot is live, so its value is `Some` and stays so (a free needs the
        // slot idle); no exclusive claim exists beside a shared one.
        unsafe { (*self.slot.value.get()).as_deref() }.unwrap_or_else(|| unreachable!("a live slot holds a value"))
    }

    /// The value, exclusive: `None` for a shared claim.
    pub fn get_mut(&mut self) -> Option<&mut T> {
        if !self.exclusive {
            return None;
        }
        // SAFETY: an exclusive claim is the only one on the slot (see `get`).
        unsafe { (*self.slot.value.get()).as_deref_mut() }
    }
}

impl<T> Drop for Claim<'_, T> {
    fn drop(&mut self) {
        if self.exclusive {
            self.slot.state.store(LIVE, Ordering::Release);
        } else {
            self.slot.state.fetch_sub(1, Ordering::AcqRel);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_check_addresses_claims_and_reuse_after_quarantine() {
        let slots: Slots<u64> = Slots::new();
        let a = slots.insert(Box::new(7)).unwrap();
        assert_eq!(*slots.claim(a, false).unwrap().get(), 7);
        // Not a slot start, and not in any segment.
        assert!(slots.find(a.cast::<u8>().wrapping_add(1).cast()).is_none());
        let x = 0u64;
        assert_eq!(slots.claim((&x as *const u64).cast(), false).err(), Some(ClaimError::NotLive));
        {
            let mut w = slots.claim(a, true).unwrap();
            *w.get_mut().unwrap() = 8;
            assert_eq!(slots.claim(a, false).err(), Some(ClaimError::Busy));
            assert_eq!(slots.remove(a).err(), Some(ClaimError::Busy));
        }
        {
            let r1 = slots.claim(a, false).unwrap();
            let mut r2 = slots.claim(a, false).unwrap();
            assert!(r2.get_mut().is_none());
            assert_eq!(slots.claim(a, true).err(), Some(ClaimError::Busy));
            assert_eq!(*r1.get() + *r2.get(), 16);
        }
        assert_eq!(*slots.remove(a).unwrap(), 8);
        assert_eq!(slots.remove(a).err(), Some(ClaimError::NotLive));
        assert_eq!(slots.claim(a, false).err(), Some(ClaimError::NotLive));
        // Growing across segments; the freed slot comes back only after the quarantine.
        let mut live: Vec<*mut Slot<u64>> = Vec::new();
        for i in 0..QUARANTINE + 1 {
            let p = slots.insert(Box::new(i as u64)).unwrap();
            assert_ne!(p, a);
            live.push(p);
        }
        for p in live.drain(..) {
            assert!(slots.remove(p).is_ok());
        }
        assert_eq!(slots.insert(Box::new(0)).unwrap(), a, "the oldest freed slot is reused first");
        assert_eq!(*slots.claim(a, false).unwrap().get(), 0);
    }
}
