//! A `#![no_std]` program that uses `hood` without its `std` feature: it builds a garment, loads
//! the shipped compact model from bytes, steps a cloth over a body for 30 frames and checks the
//! result. Allocation comes from a bump allocator over a static arena, panics abort, and the
//! only outside code is the C runtime's start-up and `write`/`_exit` (for the exit status and a
//! line of output). CI builds and runs it (`.ci/run`).

#![no_std]
#![no_main]

extern crate alloc;

use alloc::vec::Vec;
use core::alloc::{GlobalAlloc, Layout};
use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicUsize, Ordering};
use hood::body::BodyMesh;
use hood::mesh::{Garment, GarmentDesc};
use hood::model::ModelBytes;
use hood::sim::{BodyDesc, Sim, SimConfig};

/// Bytes the program may allocate in all (nothing is ever freed).
const ARENA_BYTES: usize = 64 << 20;

/// A bump allocator over a static arena: allocation moves an offset; freeing does nothing.
struct Bump {
    arena: UnsafeCell<[u8; ARENA_BYTES]>,
    used: AtomicUsize,
}

// SAFETY: the arena is only handed out in disjoint pieces (the offset moves atomically).
unsafe impl Sync for Bump {}

unsafe impl GlobalAlloc for Bump {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let base = self.arena.get() as usize;
        let mut used = self.used.load(Ordering::Relaxed);
        loop {
            let start = (base + used).next_multiple_of(layout.align()) - base;
            let end = match start.checked_add(layout.size()) {
                Some(end) if end <= ARENA_BYTES => end,
                _ => return core::ptr::null_mut(),
            };
            match self.used.compare_exchange_weak(used, end, Ordering::Relaxed, Ordering::Relaxed) {
                Ok(_) => return (base + start) as *mut u8,
                Err(now) => used = now,
            }
        }
    }

    unsafe fn dealloc(&self, _ptr: *mut u8, _layout: Layout) {}
}

#[global_allocator]
static ALLOCATOR: Bump = Bump { arena: UnsafeCell::new([0; ARENA_BYTES]), used: AtomicUsize::new(0) };

// The C library, for the start-up code that calls `main`, `write` and `_exit`.
#[link(name = "c")]
extern "C" {
    fn write(fd: i32, buf: *const u8, count: usize) -> isize;
    fn _exit(status: i32) -> !;
}

/// Writes `text` to standard error.
fn say(text: &str) {
    // SAFETY: `text` is valid for its length; fd 2 is standard error.
    unsafe { write(2, text.as_ptr(), text.len()) };
}

// The precompiled `core` and `alloc` are built to unwind, so their code names the unwinder
// (`_Unwind_Resume`, from libgcc_s) and the personality routine; with panics aborting, neither
// is ever called.
#[link(name = "gcc_s")]
extern "C" {}

/// The personality routine the precompiled libraries name (never called: panics abort).
#[no_mangle]
pub extern "C" fn rust_eh_personality() {}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    say("hood-nostd-consumer: panicked\n");
    // SAFETY: ends the process.
    unsafe { _exit(101) }
}

/// The shipped compact model, compiled in.
static MODEL: &[u8] = include_bytes!("../../models/compact.hood");

/// A 0.6 m square of cloth held 1.2 m up over a tetrahedron body that slides along x: 30 steps,
/// every position finite and the cloth fallen onto the body (below its start height).
fn run() -> hood::Result<()> {
    let (n, h) = (13u32, 0.05f32);
    let rest: Vec<[f32; 3]> = (0..n * n).map(|i| [(i % n) as f32 * h - 0.3, 1.2, (i / n) as f32 * h - 0.3]).collect();
    let faces: Vec<[u32; 3]> = (0..(n - 1) * (n - 1))
        .map(|q| q + q / (n - 1))
        .flat_map(|v| [[v, v + n, v + 1], [v + 1, v + n, v + n + 1]])
        .collect();
    let garment = Garment::new(GarmentDesc::new(&rest, &faces))?;
    let body = BodyMesh::new(4, &[[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])?;
    let mut frame = [[-0.4, 0.0, -0.4], [0.4, 0.0, -0.4], [0.0, 0.0, 0.4], [0.0, 1.0, 0.0]];
    let bytes = ModelBytes::new(MODEL);
    let model = bytes.model()?;
    let mut sim = Sim::new(&model, &garment, Some(BodyDesc { mesh: &body, positions: &frame }), SimConfig::network())?;
    let mut lowest = f32::INFINITY;
    for _ in 0..30 {
        frame.iter_mut().for_each(|p| p[0] += 0.01);
        let x = sim.step(&frame)?;
        if !x.iter().flatten().all(|c| c.is_finite()) {
            return Err(hood::Error::NonFinite { what: "garment position", index: 0 });
        }
        lowest = x.iter().map(|p| p[1]).fold(lowest, f32::min);
    }
    if lowest >= 1.2 {
        say("hood-nostd-consumer: the cloth did not move\n");
        // SAFETY: ends the process.
        unsafe { _exit(1) }
    }
    Ok(())
}

/// The C runtime's entry point.
#[no_mangle]
pub extern "C" fn main(_argc: i32, _argv: *const *const u8) -> i32 {
    match run() {
        Ok(()) => {
            say("hood-nostd-consumer: 30 steps without std, finite, the cloth falling\n");
            0
        }
        Err(_) => {
            say("hood-nostd-consumer: a step returned an error\n");
            1
        }
    }
}
