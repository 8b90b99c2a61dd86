//! Thread CPU time: the clock of the measured bf16 choice ([`super::bf16_choice`]) and, with the
//! tools, of the peak and kernel timings (re-exported as `kernels::peak::Stopwatch`).

use std::time::Instant;

/// Seconds of CPU time this thread has run (`CLOCK_THREAD_CPUTIME_ID` on 64-bit Linux, which
/// counts only time on a CPU, so a busy shared machine does not inflate it), or `None` elsewhere.
pub fn thread_cpu_seconds() -> Option<f64> {
    #[cfg(all(target_os = "linux", target_pointer_width = "64"))]
    {
        #[repr(C)]
        struct Timespec {
            tv_sec: i64,
            tv_nsec: i64,
        }
        extern "C" {
            fn clock_gettime(clock: i32, tp: *mut Timespec) -> i32;
        }
        const CLOCK_THREAD_CPUTIME_ID: i32 = 3;
        let mut ts = Timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: glibc/musl `clock_gettime` with a valid clock id writes one `timespec`, which on
        // 64-bit Linux is two 64-bit integers, matching `Timespec`; `ts` is a live local.
        let rc = unsafe { clock_gettime(CLOCK_THREAD_CPUTIME_ID, &mut ts) };
        if rc == 0 {
            return Some(ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9);
        }
    }
    None
}

/// A stopwatch on thread CPU time where the OS offers it, else on wall time.
#[derive(Clone, Copy, Debug)]
pub struct Stopwatch {
    cpu: Option<f64>,
    wall: Instant,
}

impl Stopwatch {
    /// Starts timing.
    pub fn start() -> Stopwatch {
        Stopwatch { cpu: thread_cpu_seconds(), wall: Instant::now() }
    }
    /// Seconds since `start` (CPU time of this thread if available).
    pub fn seconds(&self) -> f64 {
        match (self.cpu, thread_cpu_seconds()) {
            (Some(a), Some(b)) => b - a,
            _ => self.wall.elapsed().as_secs_f64(),
        }
    }
    /// Whether this stopwatch measures thread CPU time (else wall time).
    #[cfg(feature = "tools")]
    pub fn is_cpu_time(&self) -> bool {
        self.cpu.is_some()
    }
}
