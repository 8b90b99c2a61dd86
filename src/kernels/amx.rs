//! The AMX-BF16 path: bf16 matrix products on the tile unit (Intel Sapphire Rapids and later).
//!
//! What AMX needs, and where this file does it:
//!
//! * **Detection** ([`usable`]): CPUID reports AMX-TILE and AMX-BF16, the OS saves the tile state
//!   (XCR0 bits 17 and 18), and on Linux the process asked for the tile data with
//!   `arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`, which this file does once. Other
//!   operating systems are not asked, and AMX stays off there.
//! * **Tile configuration** ([`configure`] / [`release`]): eight tiles of 16 rows × 64 bytes, loaded
//!   at the start of each kernel call that multiplies bf16 weights and released at its end, so the
//!   thread carries no tile state between calls.
//! * **The product** ([`gemm`]): `C[16 × 16 f32] += A[16 × 32 bf16] · B[32 × 16 bf16]` per
//!   `tdpbf16ps`. The packed bf16 panels (see `pack`) are already in the B-tile layout (per input
//!   pair one 64-byte row of 16 columns × (even, odd)), and the prepared activations are rows of
//!   bf16 pairs, so both load straight from where they are. Up to 2 × 2 output tiles accumulate
//!   at once (tiles 0-3), with two A tiles (4, 5) and two B tiles (6, 7). Inputs past the last
//!   whole 32 of an operand are added with `vdpbf16ps` on the stored tile, and the epilogue is the
//!   register tiles' ([`frame::epilogue_row`]).
//!
//! Stable Rust has no AMX intrinsics or target features: the instructions are written as inline
//! assembly with the tile registers named in the text, which the assembler accepts without them.

use core::arch::asm;
use core::sync::atomic::{AtomicU8, Ordering};

use super::frame::{self, SegBf16, Simd, TileEpi};
use super::PANEL;

/// Rows of an A or C tile (and input pairs of a B tile).
const TILE_ROWS: usize = 16;
/// Input pairs one A tile row (and one B tile) covers: 64 bytes of bf16 pairs.
const TILE_PAIRS: usize = 16;

/// 0: not probed, 1: no AMX, 2: AMX usable.
static USABLE: AtomicU8 = AtomicU8::new(0);

/// Whether this process may run AMX-BF16 instructions (probed and permitted once).
pub(crate) fn usable() -> bool {
    match USABLE.load(Ordering::Relaxed) {
        1 => false,
        2 => true,
        _ => {
            let ok = probe();
            USABLE.store(if ok { 2 } else { 1 }, Ordering::Relaxed);
            ok
        }
    }
}

fn probe() -> bool {
    use core::arch::x86_64::__cpuid_count;
    // CPUID leaf 7: EDX bit 22 AMX-BF16, bit 24 AMX-TILE. Leaf 1: ECX bit 27 OSXSAVE.
    let leaf0 = __cpuid_count(0, 0);
    if leaf0.eax < 0x1D {
        return false;
    }
    let l7 = __cpuid_count(7, 0);
    let l1 = __cpuid_count(1, 0);
    if l7.edx & (1 << 22) == 0 || l7.edx & (1 << 24) == 0 || l1.ecx & (1 << 27) == 0 {
        return false;
    }
    // Palette 1 (leaf 0x1D, subleaf 1) must offer the tiles configured here: EBX holds bytes per
    // row (low half) and tile names (high half), ECX the rows.
    let palette = __cpuid_count(0x1D, 1);
    let (bytes_per_row, max_names, max_rows) = (palette.ebx & 0xFFFF, palette.ebx >> 16, palette.ecx & 0xFFFF);
    if bytes_per_row < 64 || max_names < 8 || max_rows < TILE_ROWS as u32 {
        return false;
    }
    // XCR0 bits 17 (XTILECFG) and 18 (XTILEDATA): the OS saves the tile state.
    let (lo, _hi): (u32, u32);
    // SAFETY: OSXSAVE is set (checked above), so `xgetbv` exists and reads XCR0 for ECX = 0.
    unsafe { asm!("xgetbv", in("ecx") 0u32, out("eax") lo, out("edx") _hi, options(nomem, nostack, preserves_flags)) };
    if lo & (0b11 << 17) != 0b11 << 17 {
        return false;
    }
    request_tile_data()
}

/// Asks Linux for the tile data state (`arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`),
/// once per process; without it the first tile instruction kills the process.
#[cfg(target_os = "linux")]
fn request_tile_data() -> bool {
    const SYS_ARCH_PRCTL: i64 = 158;
    const ARCH_REQ_XCOMP_PERM: i64 = 0x1023;
    const XFEATURE_XTILEDATA: i64 = 18;
    let ret: i64;
    // SAFETY: a plain system call with integer arguments; it touches no memory of ours and the
    // kernel preserves every register but rax, rcx and r11.
    unsafe {
        asm!(
            "syscall",
            inlateout("rax") SYS_ARCH_PRCTL => ret,
            in("rdi") ARCH_REQ_XCOMP_PERM,
            in("rsi") XFEATURE_XTILEDATA,
            lateout("rcx") _,
            lateout("r11") _,
            options(nostack),
        )
    };
    ret == 0
}

#[cfg(not(target_os = "linux"))]
fn request_tile_data() -> bool {
    false
}

/// The tile configuration: palette 1, all eight tiles 16 rows × 64 bytes.
#[repr(C, align(64))]
struct TileConfig([u8; 64]);

const CONFIG: TileConfig = {
    let mut c = [0u8; 64];
    c[0] = 1;
    let mut t = 0;
    while t < 8 {
        c[16 + 2 * t] = 64;
        c[48 + t] = TILE_ROWS as u8;
        t += 1;
    }
    TileConfig(c)
};

/// Loads the tile configuration (zeroing every tile).
///
/// # Safety
/// [`usable`] returned true in this process.
#[inline(always)]
pub(crate) unsafe fn configure() {
    // SAFETY: AMX is usable (the caller's contract); CONFIG is 64 aligned, readable bytes.
    unsafe { asm!("ldtilecfg [{c}]", c = in(reg) &CONFIG, options(nostack, readonly, preserves_flags)) };
}

/// Returns the tiles to their initial state.
///
/// # Safety
/// [`usable`] returned true in this process.
#[inline(always)]
pub(crate) unsafe fn release() {
    // SAFETY: AMX is usable (the caller's contract).
    unsafe { asm!("tilerelease", options(nomem, nostack, preserves_flags)) };
}

/// `tileloadd tmmT, [p + stride]`: 16 rows of 64 bytes, `stride` bytes apart.
macro_rules! load {
    ($t:literal, $p:expr, $stride:expr) => {
        asm!(
            concat!("tileloadd tmm", $t, ", [{p} + {s}]"),
            p = in(reg) $p,
            s = in(reg) $stride,
            options(nostack, readonly, preserves_flags)
        )
    };
}

/// `tilestored [p + 64], tmmT`: 16 rows of 64 bytes, packed.
macro_rules! store {
    ($t:literal, $p:expr) => {
        asm!(
            concat!("tilestored [{p} + {s}], tmm", $t),
            p = in(reg) $p,
            s = in(reg) 64usize,
            options(nostack, preserves_flags)
        )
    };
}

/// `tdpbf16ps tmmC, tmmA, tmmB`: C += A · B.
macro_rules! dot {
    ($c:literal, $a:literal, $b:literal) => {
        asm!(concat!("tdpbf16ps tmm", $c, ", tmm", $a, ", tmm", $b), options(nomem, nostack, preserves_flags))
    };
}

/// `tdpbf16ps` for the tile numbers `(C, A, B)`, one of the listed triples (each a literal
/// instruction: the tile registers are named in the text).
macro_rules! tile_dots {
    ($c:expr, $a:expr, $b:expr; $(($tc:literal, $ta:literal, $tb:literal)),* $(,)?) => {
        match ($c, $a, $b) {
            $(($tc, $ta, $tb) => dot!($tc, $ta, $tb),)*
            // Ruled out at compile time by the caller's assertion on the triple.
            _ => unreachable!(),
        }
    };
}

macro_rules! zero {
    ($t:literal) => {
        asm!(concat!("tilezero tmm", $t), options(nomem, nostack, preserves_flags))
    };
}

/// The four tile operations [`gemm`] issues, on the tile unit ([`Hardware`]) or, in tests, on a
/// software model of it (`Emulator`), so that the product's tiling, tails and layouts are checked
/// on CPUs without AMX. Tiles are numbered as in the instructions (`tmm0`-`tmm7`) and configured
/// as [`configure`] does: 16 rows of 64 bytes.
///
/// # Safety
/// An implementation must do what the instruction it stands for does, on the memory it names.
pub(crate) unsafe trait TileUnit {
    /// Whether this process may use the unit (for the hardware: [`usable`]).
    fn available() -> bool;
    /// Sets the unit up for this thread (for the hardware: [`configure`]).
    ///
    /// # Safety
    /// [`TileUnit::available`] returned true.
    unsafe fn configure();
    /// Undoes [`TileUnit::configure`] (for the hardware: [`release`]).
    ///
    /// # Safety
    /// As [`TileUnit::configure`].
    unsafe fn release();
    /// A handle on a unit that [`configure`] (for the hardware) has set up on this thread.
    ///
    /// # Safety
    /// [`TileUnit::available`] returned true, and for the hardware the tiles are configured.
    unsafe fn on_this_thread() -> Self;
    /// `tilezero tmmT`.
    fn zero<const T: usize>(&mut self);
    /// `tileloadd tmmT, [p + stride]`: 16 rows of 64 bytes, the rows `stride` bytes apart.
    ///
    /// # Safety
    /// The 16 rows are readable.
    unsafe fn load<const T: usize>(&mut self, p: *const f32, stride: usize);
    /// `tilestored [p + 64], tmmT`: 16 rows of 64 bytes, packed.
    ///
    /// # Safety
    /// 1 KiB is writable at `p`.
    unsafe fn store<const T: usize>(&mut self, p: *mut f32);
    /// `tdpbf16ps tmmC, tmmA, tmmB`: per row `m` and column `n` of C,
    /// `C[m][n] += Σ_k A[m][2k] · B[k][2n] + A[m][2k+1] · B[k][2n+1]` over the bf16 pairs.
    fn dot<const C: usize, const A: usize, const B: usize>(&mut self);
}

/// The tile unit itself.
pub(crate) struct Hardware(());

// SAFETY: each method is the instruction it names; `on_this_thread` requires the configuration.
unsafe impl TileUnit for Hardware {
    fn available() -> bool {
        usable()
    }
    #[inline(always)]
    unsafe fn configure() {
        // SAFETY: forwarded contract.
        unsafe { configure() }
    }
    #[inline(always)]
    unsafe fn release() {
        // SAFETY: forwarded contract.
        unsafe { release() }
    }
    #[inline(always)]
    unsafe fn on_this_thread() -> Self {
        Hardware(())
    }
    #[inline(always)]
    fn zero<const T: usize>(&mut self) {
        const { assert!(T < 8) };
        // SAFETY: a `Hardware` exists only on a configured thread (`on_this_thread`'s contract);
        // the instruction touches no memory.
        unsafe {
            match T {
                0 => zero!("0"),
                1 => zero!("1"),
                2 => zero!("2"),
                3 => zero!("3"),
                4 => zero!("4"),
                5 => zero!("5"),
                6 => zero!("6"),
                _ => zero!("7"),
            }
        }
    }
    #[inline(always)]
    unsafe fn load<const T: usize>(&mut self, p: *const f32, stride: usize) {
        const { assert!(T >= 2 && T < 8) };
        // SAFETY: configured (as above); the caller guarantees the rows are readable.
        unsafe {
            match T {
                2 => load!("2", p, stride),
                3 => load!("3", p, stride),
                4 => load!("4", p, stride),
                5 => load!("5", p, stride),
                6 => load!("6", p, stride),
                _ => load!("7", p, stride),
            }
        }
    }
    #[inline(always)]
    unsafe fn store<const T: usize>(&mut self, p: *mut f32) {
        const { assert!(T < 4) };
        // SAFETY: configured (as above); the caller guarantees 1 KiB is writable at `p`.
        unsafe {
            match T {
                0 => store!("0", p),
                1 => store!("1", p),
                2 => store!("2", p),
                _ => store!("3", p),
            }
        }
    }
    #[inline(always)]
    fn dot<const C: usize, const A: usize, const B: usize>(&mut self) {
        // The products `gemm` uses (output tile (row tile, panel) from A tile 4 + row tile and
        // B tile 6 + panel), and the trainer's split products (`train::gemm`: output tiles 0
        // and 1 from A tiles 2-4 and B tiles 5-7).
        const { assert!((C < 4 && A == 4 + C / 2 && B == 6 + C % 2) || (C < 2 && A >= 2 && A <= 4 && B >= 5 && B <= 7)) };
        // SAFETY: configured (as above); the instruction touches no memory.
        unsafe {
            tile_dots!(C, A, B;
                (0, 4, 6), (1, 4, 7), (2, 5, 6), (3, 5, 7),
                (0, 2, 5), (0, 2, 6), (0, 2, 7), (0, 3, 5), (0, 3, 6), (0, 3, 7), (0, 4, 5), (0, 4, 7),
                (1, 2, 5), (1, 2, 6), (1, 2, 7), (1, 3, 5), (1, 3, 6), (1, 3, 7), (1, 4, 5), (1, 4, 6)
            )
        }
    }
}

/// A software model of the tile unit, for tests on CPUs without AMX: eight tiles of 16 rows of
/// 16 words, and `tdpbf16ps` as Intel's pseudocode defines it (per pair the even then the odd
/// product accumulated in f32, rounded to nearest even, subnormal inputs read as zero and
/// subnormal sums flushed to zero).
#[cfg(any(test, feature = "train"))]
pub(crate) struct Emulator {
    tiles: [[u32; TILE_ROWS * 16]; 8],
}

#[cfg(any(test, feature = "train"))]
impl Emulator {
    /// A bf16 (the high half of an f32) as f32, subnormals read as zero.
    fn widen(bits: u32) -> f32 {
        let v = f32::from_bits(bits << 16);
        if v.is_subnormal() {
            0.0
        } else {
            v
        }
    }
}

// SAFETY: each method does what its instruction does, on the memory the instruction would touch.
#[cfg(any(test, feature = "train"))]
unsafe impl TileUnit for Emulator {
    fn available() -> bool {
        true
    }
    unsafe fn configure() {}
    unsafe fn release() {}
    unsafe fn on_this_thread() -> Self {
        // Tiles start zeroed, as `ldtilecfg` leaves them.
        Emulator { tiles: [[0; TILE_ROWS * 16]; 8] }
    }
    fn zero<const T: usize>(&mut self) {
        self.tiles[T] = [0; TILE_ROWS * 16];
    }
    unsafe fn load<const T: usize>(&mut self, p: *const f32, stride: usize) {
        for r in 0..TILE_ROWS {
            // SAFETY: the caller guarantees row `r` (64 bytes at `p + r · stride`) is readable.
            let row = unsafe { core::slice::from_raw_parts((p as *const u8).add(r * stride), 64) };
            for (w, b) in self.tiles[T][r * 16..(r + 1) * 16].iter_mut().zip(row.chunks_exact(4)) {
                *w = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
        }
    }
    unsafe fn store<const T: usize>(&mut self, p: *mut f32) {
        for (i, w) in self.tiles[T].iter().enumerate() {
            // SAFETY: the caller guarantees 1 KiB is writable at `p`; a tile is 1 KiB.
            unsafe { (p as *mut u8).add(4 * i).cast::<[u8; 4]>().write_unaligned(w.to_le_bytes()) };
        }
    }
    fn dot<const C: usize, const A: usize, const B: usize>(&mut self) {
        let (a, b) = (self.tiles[A], self.tiles[B]);
        let c = &mut self.tiles[C];
        for m in 0..TILE_ROWS {
            for n in 0..16 {
                let mut acc = f32::from_bits(c[m * 16 + n]);
                for k in 0..TILE_PAIRS {
                    let (x, w) = (a[m * 16 + k], b[k * 16 + n]);
                    // The product of two bf16 is exact in f32: one rounding per accumulation.
                    for half in [0, 16] {
                        acc += Self::widen((x >> half) & 0xFFFF) * Self::widen((w >> half) & 0xFFFF);
                        if acc.is_subnormal() {
                            acc = 0.0f32.copysign(acc);
                        }
                    }
                }
                c[m * 16 + n] = acc.to_bits();
            }
        }
    }
}

/// Four output tiles (2 row tiles × 2 panels) of 16 × 16 `f32`.
#[repr(C, align(64))]
struct Out([[f32; TILE_ROWS * PANEL]; 4]);

/// One A tile of 16 rows × 16 pairs, for row tails.
#[repr(C, align(64))]
struct RowTail([f32; TILE_ROWS * TILE_PAIRS]);

/// `out[rows × n] (+)= epilogue(Σ segs)` on the tile unit `U` (the bf16 half of `frame::gemm`).
///
/// # Safety
/// The CPU supports `S` (AVX-512-BF16) and `U` is set up on this thread ([`TileUnit::configure`]); the
/// operands are those `frame::gemm` takes: every segment has `rows` rows of `ldx` slots and packed
/// weights of `ceil(n/16)` panels of `pairs` input pairs; `out` has `rows` rows of stride
/// `ldo >= n`; the epilogue's pointers cover `rows` rows of `n` columns.
#[inline(always)]
pub(crate) unsafe fn gemm<S: Simd, U: TileUnit>(
    s: S,
    segs: &[SegBf16],
    rows: usize,
    n: usize,
    out: *mut f32,
    ldo: usize,
    epi: &TileEpi,
) {
    // SAFETY: the caller's contract.
    let u = &mut unsafe { U::on_this_thread() };
    let panels = n.div_ceil(PANEL);
    let mut c = Out([[0.0; TILE_ROWS * PANEL]; 4]);
    let mut tail = RowTail([0.0; TILE_ROWS * TILE_PAIRS]);
    // SAFETY (whole body): tile loads read 16 rows of 64 bytes at a row stride that keeps them
    // inside the operand (full row tiles) or in `tail` (the last, partial one); weight tiles read
    // 16 whole pair rows of a panel that exists; stores go to `c`; the epilogue writes rows below
    // `rows` and columns below `n`. The unit is set up (the caller's contract).
    unsafe {
        for p0 in (0..panels).step_by(2) {
            let two_panels = p0 + 1 < panels;
            for r0 in (0..rows).step_by(2 * TILE_ROWS) {
                let nr = (rows - r0).min(2 * TILE_ROWS);
                let two_rows = nr > TILE_ROWS;
                // Only the output tiles this block covers.
                u.zero::<0>();
                if two_panels {
                    u.zero::<1>();
                }
                if two_rows {
                    u.zero::<2>();
                    if two_panels {
                        u.zero::<3>();
                    }
                }
                for seg in segs {
                    let kp = 2 * seg.pairs;
                    for q in (0..seg.pairs / TILE_PAIRS).map(|i| i * TILE_PAIRS) {
                        let w0 = seg.w.add(p0 * PANEL * kp + q * 2 * PANEL);
                        u.load::<6>(w0 as *const f32, 64);
                        if two_panels {
                            u.load::<7>(w0.add(PANEL * kp) as *const f32, 64);
                        }
                        let a0 = a_tile(seg, r0, nr.min(TILE_ROWS), q, &mut tail);
                        u.load::<4>(a0.0, a0.1);
                        u.dot::<0, 4, 6>();
                        if two_panels {
                            u.dot::<1, 4, 7>();
                        }
                        if two_rows {
                            let a1 = a_tile(seg, r0 + TILE_ROWS, nr - TILE_ROWS, q, &mut tail);
                            u.load::<5>(a1.0, a1.1);
                            u.dot::<2, 5, 6>();
                            if two_panels {
                                u.dot::<3, 5, 7>();
                            }
                        }
                    }
                }
                u.store::<0>(c.0[0].as_mut_ptr());
                if two_panels {
                    u.store::<1>(c.0[1].as_mut_ptr());
                }
                if two_rows {
                    u.store::<2>(c.0[2].as_mut_ptr());
                    if two_panels {
                        u.store::<3>(c.0[3].as_mut_ptr());
                    }
                }
                for r in 0..nr {
                    for pj in 0..if two_panels { 2 } else { 1 } {
                        let t = (r / TILE_ROWS) * 2 + pj;
                        let row = c.0[t].as_mut_ptr().add((r % TILE_ROWS) * PANEL);
                        let mut acc = s.load(row);
                        // Pairs past the last whole tile, on the vector unit.
                        for seg in segs {
                            let kp = 2 * seg.pairs;
                            for q in seg.pairs / TILE_PAIRS * TILE_PAIRS..seg.pairs {
                                let w = s.load_w2(seg.w.add((p0 + pj) * PANEL * kp + q * 2 * PANEL));
                                acc = s.dot2(acc, w, s.bcast_x2(seg.x.add((r0 + r) * seg.ldx + q)));
                            }
                        }
                        s.store(row, acc);
                        frame::epilogue_row(s, row, r0 + r, (p0 + pj) * PANEL, n, out, ldo, epi);
                    }
                }
            }
        }
    }
}

/// Address and row stride (bytes) of the A tile for rows `r0..r0 + nr` (`nr <= 16`) and pairs
/// `q..q + 16` of `seg`: in place for 16 rows, else copied into `tail` (its other rows zero).
///
/// # Safety
/// Rows `r0..r0 + nr` and pairs `q..q + 16` exist in `seg`.
#[inline(always)]
unsafe fn a_tile(seg: &SegBf16, r0: usize, nr: usize, q: usize, tail: &mut RowTail) -> (*const f32, usize) {
    // SAFETY: the caller's contract; `tail` holds 16 rows of 16 slots.
    unsafe {
        if nr == TILE_ROWS {
            return (seg.x.add(r0 * seg.ldx + q), seg.ldx * 4);
        }
        for r in 0..TILE_ROWS {
            let dst = tail.0.as_mut_ptr().add(r * TILE_PAIRS);
            if r < nr {
                core::ptr::copy_nonoverlapping(seg.x.add((r0 + r) * seg.ldx + q), dst, TILE_PAIRS);
            } else {
                core::ptr::write_bytes(dst, 0, TILE_PAIRS);
            }
        }
        (tail.0.as_ptr(), TILE_PAIRS * 4)
    }
}

/// The tile unit's throughput loop for [`super::peak`]: `iters` rounds of four independent
/// `tdpbf16ps` (16 × 16 outputs × 32 products each), `iters · 4 · 16 · 16 · 32 · 2` FLOPs, on
/// zero tiles (the rate does not depend on the values).
#[cfg(feature = "tools")]
pub(crate) fn peak_loop(_t: super::x86::AmxBf16, iters: usize) -> f32 {
    let mut c = Out([[0.0; TILE_ROWS * PANEL]; 4]);
    // SAFETY: the token proves AMX is usable; the tiles are configured first and released last;
    // the stores write `c`.
    unsafe {
        configure();
        let mut u = Hardware::on_this_thread();
        for _ in 0..iters {
            u.dot::<0, 4, 6>();
            u.dot::<1, 4, 7>();
            u.dot::<2, 5, 6>();
            u.dot::<3, 5, 7>();
        }
        u.store::<0>(c.0[0].as_mut_ptr());
        release();
    }
    c.0[0][0]
}
