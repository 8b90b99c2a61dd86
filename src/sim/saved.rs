//! The whole state of a [`Sim`] between steps as bytes, for save games, rollback netcode and
//! swapping a garment's level of detail back: garment positions and velocities, pin targets, the
//! body's previous and current frames, whether the start-up step has run, the sleeping count and
//! the speed limit's last carry. A sim of the same garment, body and configuration that loads
//! the bytes continues bitwise as the saving one would have.
//!
//! Layout (little-endian): the magic `HDST`, the format version, the garment and body vertex
//! counts, flags (bit 0: started), the sleeping count, the last carry (3 × f32, m), then the
//! positions, velocities and pin targets of the garment and the previous and current body
//! positions (3 × f32 each, m and m/frame), and a CRC-32 of everything before it.

use super::Sim;
use crate::checksum::crc32;
use crate::error::{Error, Result};
use crate::math::finite3;

/// The first four bytes of a saved state.
pub const STATE_MAGIC: [u8; 4] = *b"HDST";
/// The version of the layout this build writes and reads.
pub const STATE_VERSION: u32 = 1;
/// Bytes before the arrays.
const HEADER: usize = 36;

/// Little-endian reader over a checked buffer (lengths are validated before reading).
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn u32(&mut self) -> u32 {
        let v = u32::from_le_bytes([
            self.bytes[self.at],
            self.bytes[self.at + 1],
            self.bytes[self.at + 2],
            self.bytes[self.at + 3],
        ]);
        self.at += 4;
        v
    }
    fn f32(&mut self) -> f32 {
        f32::from_bits(self.u32())
    }
    fn point(&mut self) -> [f32; 3] {
        [self.f32(), self.f32(), self.f32()]
    }
}

fn put(out: &mut [u8], at: &mut usize, v: u32) {
    out[*at..*at + 4].copy_from_slice(&v.to_le_bytes());
    *at += 4;
}

fn put_points(out: &mut [u8], at: &mut usize, points: &[[f32; 3]]) {
    for p in points {
        for c in p {
            put(out, at, c.to_bits());
        }
    }
}

impl Sim<'_> {
    /// Bytes [`Sim::save_state`] writes for this sim.
    pub fn saved_state_len(&self) -> usize {
        let (n, nb) = (self.state.pos.len(), self.state.body_pos.len());
        HEADER + 12 * (3 * n + 2 * nb) + 4
    }

    /// Writes the state into the start of `out` and returns the bytes written
    /// ([`Sim::saved_state_len`]). Allocates nothing.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `out` is shorter than [`Sim::saved_state_len`].
    pub fn save_state(&self, out: &mut [u8]) -> Result<usize> {
        let len = self.saved_state_len();
        if out.len() < len {
            return Err(Error::SizeMismatch { what: "saved state buffer", expected: len, got: out.len() });
        }
        let s = &self.state;
        let mut at = 0;
        out[..4].copy_from_slice(&STATE_MAGIC);
        at += 4;
        for v in [STATE_VERSION, s.pos.len() as u32, s.body_pos.len() as u32, s.started as u32, self.rest_frames] {
            put(out, &mut at, v);
        }
        put_points(out, &mut at, core::slice::from_ref(&self.last_carry));
        for points in [&s.pos, &s.velocity, &self.pin_targets, &s.body_prev, &s.body_pos] {
            put_points(out, &mut at, points);
        }
        let crc = crc32(&out[..at]);
        put(out, &mut at, crc);
        Ok(at)
    }

    /// Restores a state [`Sim::save_state`] wrote, from a sim of the same garment and body
    /// (vertex counts are checked; the configuration is this sim's). Allocates nothing; on
    /// error the state is unchanged. [`Sim::last_effects`] reads all false until the next step.
    ///
    /// # Errors
    /// [`Error::CorruptData`] for bytes that are not a saved state of this version, fail their
    /// checksum or are truncated; [`Error::SizeMismatch`] for other vertex counts;
    /// [`Error::NonFinite`] for a non-finite value.
    pub fn load_state(&mut self, bytes: &[u8]) -> Result<()> {
        let corrupt = |reason| Error::CorruptData { reason };
        if bytes.len() < HEADER + 4 || bytes[..4] != STATE_MAGIC {
            return Err(corrupt("not a saved sim state (magic)"));
        }
        let mut r = Reader { bytes, at: 4 };
        if r.u32() != STATE_VERSION {
            return Err(corrupt("saved sim state of another version"));
        }
        let (n, nb) = (r.u32() as usize, r.u32() as usize);
        let (want_n, want_nb) = (self.state.pos.len(), self.state.body_pos.len());
        if n != want_n {
            return Err(Error::SizeMismatch { what: "saved state garment vertices", expected: want_n, got: n });
        }
        if nb != want_nb {
            return Err(Error::SizeMismatch { what: "saved state body vertices", expected: want_nb, got: nb });
        }
        let len = self.saved_state_len();
        if bytes.len() != len {
            return Err(corrupt("saved sim state truncated or padded"));
        }
        let stored = u32::from_le_bytes([bytes[len - 4], bytes[len - 3], bytes[len - 2], bytes[len - 1]]);
        if crc32(&bytes[..len - 4]) != stored {
            return Err(corrupt("saved sim state fails its checksum"));
        }
        let flags = r.u32();
        if flags > 1 {
            return Err(corrupt("saved sim state flags"));
        }
        let rest_frames = r.u32();
        let carry = r.point();
        // Check every value before changing anything (pin targets only where pinned).
        let arrays = r.at;
        let what = ["saved garment position", "saved garment velocity", "saved pin target", "saved body position"];
        for k in 0..3 * n + 2 * nb {
            let p = r.point();
            // Which array (0-2 of the garment, 3 the body's two) and the vertex in it.
            let (array, i) = if k < 3 * n { (k / n, k % n) } else { (3, (k - 3 * n) % nb) };
            if array == 2 && !self.pinned[i] {
                continue;
            }
            if !finite3(p) {
                return Err(Error::NonFinite { what: what[array], index: i });
            }
        }
        if !finite3(carry) {
            return Err(Error::NonFinite { what: "saved speed-limit carry", index: 0 });
        }
        r.at = arrays;
        let s = &mut self.state;
        for dst in [&mut s.pos, &mut s.velocity, &mut self.pin_targets, &mut s.body_prev, &mut s.body_pos] {
            for p in dst.iter_mut() {
                *p = r.point();
            }
        }
        s.started = flags & 1 == 1;
        self.rest_frames = rest_frames;
        self.last_carry = carry;
        // A report of this sim's last step, not part of the state: none has run from it yet.
        self.report_no_step(super::StepEffects::default());
        if self.cfg.normals {
            crate::mesh::vertex_normals(self.garment.faces(), &self.state.pos, &mut self.output_normals);
        }
        Ok(())
    }
}
