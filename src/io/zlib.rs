//! zlib streams (RFC 1950) of deflate data (RFC 1951), written without a dependency: stored
//! blocks, and a compressor pairing LZ77 over a 32 KiB window (hash chains, greedy matches)
//! with the fixed Huffman codes of the format. Good enough for rendered previews (flat regions,
//! repeated rows: a strip shrinks about tenfold); not a general-purpose zlib.

use std::vec;
use std::vec::Vec;

/// Adler-32 as zlib streams end with.
pub fn adler32(bytes: &[u8]) -> u32 {
    let (mut a, mut b) = (1u32, 0u32);
    // 5552 bytes is the most that cannot overflow `b` before the reduction.
    for chunk in bytes.chunks(5552) {
        for &x in chunk {
            a += x as u32;
            b += a;
        }
        a %= 65521;
        b %= 65521;
    }
    (b << 16) | a
}

/// A zlib stream of `data` in stored (uncompressed) deflate blocks.
pub fn stored(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len() + data.len() / 65535 * 5 + 16);
    out.extend_from_slice(&[0x78, 0x01]);
    let mut blocks = data.chunks(65535).peekable();
    if blocks.peek().is_none() {
        out.extend_from_slice(&[1, 0, 0, 0xFF, 0xFF]);
    }
    while let Some(block) = blocks.next() {
        out.push(u8::from(blocks.peek().is_none()));
        let len = block.len() as u16;
        out.extend_from_slice(&len.to_le_bytes());
        out.extend_from_slice(&(!len).to_le_bytes());
        out.extend_from_slice(block);
    }
    out.extend_from_slice(&adler32(data).to_be_bytes());
    out
}

/// A compressed zlib stream of `data`: one deflate block with the fixed Huffman codes, or
/// stored blocks when those come out shorter (incompressible data).
pub fn compress(data: &[u8]) -> Vec<u8> {
    let mut w = BitWriter { out: Vec::with_capacity(data.len() / 4 + 64), acc: 0, n: 0 };
    w.out.extend_from_slice(&[0x78, 0x9C]);
    w.bits(1, 1); // BFINAL: the only block
    w.bits(1, 2); // BTYPE 01: fixed Huffman codes
    Matcher::new(data.len()).encode(data, &mut w);
    w.literal_or_length(256); // end of block
    w.flush();
    w.out.extend_from_slice(&adler32(data).to_be_bytes());
    let plain = stored(data);
    if plain.len() < w.out.len() {
        plain
    } else {
        w.out
    }
}

/// Deflate's window: the farthest a match may look back.
const WINDOW: usize = 32 * 1024;
/// Shortest and longest match deflate can express.
const MIN_MATCH: usize = 3;
const MAX_MATCH: usize = 258;
/// Hash chain entries followed per position at most.
const MAX_CHAIN: usize = 48;
/// A match this long ends the chain walk early.
const GOOD_ENOUGH: usize = 128;
const HASH_BITS: u32 = 15;
const NO_POS: u32 = u32::MAX;

/// Base lengths of the length symbols 257..=285 and their extra bits.
const LENGTH_BASE: [u16; 29] =
    [3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115, 131, 163, 195, 227, 258];
const LENGTH_EXTRA: [u8; 29] = [0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0];
/// Base distances of the distance symbols 0..=29 and their extra bits.
const DIST_BASE: [u16; 30] = [
    1, 2, 3, 4, 5, 7, 9, 13, 17, 25, 33, 49, 65, 97, 129, 193, 257, 385, 513, 769, 1025, 1537, 2049, 3073, 4097, 6145,
    8193, 12289, 16385, 24577,
];
const DIST_EXTRA: [u8; 30] =
    [0, 0, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7, 8, 8, 9, 9, 10, 10, 11, 11, 12, 12, 13, 13];

/// Deflate's bit order: values fill bytes from the least significant bit; Huffman codes are
/// sent from their most significant bit, so they are reversed on the way in.
struct BitWriter {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

impl BitWriter {
    /// Appends the `count` low bits of `value`, least significant first.
    fn bits(&mut self, value: u32, count: u32) {
        self.acc |= u64::from(value) << self.n;
        self.n += count;
        while self.n >= 8 {
            self.out.push(self.acc as u8);
            self.acc >>= 8;
            self.n -= 8;
        }
    }

    /// Appends a Huffman code of `len` bits, most significant first.
    fn code(&mut self, code: u32, len: u32) {
        self.bits(code.reverse_bits() >> (32 - len), len);
    }

    /// A literal byte (0..=255), the end of block (256) or a length symbol (257..=287) in the
    /// fixed code.
    fn literal_or_length(&mut self, sym: u32) {
        match sym {
            0..=143 => self.code(0x30 + sym, 8),
            144..=255 => self.code(0x190 + sym - 144, 9),
            256..=279 => self.code(sym - 256, 7),
            _ => self.code(0xC0 + sym - 280, 8),
        }
    }

    /// A match of `len` (3..=258) bytes `dist` (1..=32768) back.
    fn match_(&mut self, len: usize, dist: usize) {
        let l = LENGTH_BASE.partition_point(|&b| b as usize <= len) - 1;
        self.literal_or_length(257 + l as u32);
        self.bits((len - LENGTH_BASE[l] as usize) as u32, LENGTH_EXTRA[l] as u32);
        let d = DIST_BASE.partition_point(|&b| b as usize <= dist) - 1;
        self.code(d as u32, 5);
        self.bits((dist - DIST_BASE[d] as usize) as u32, DIST_EXTRA[d] as u32);
    }

    /// Pads the last byte with zero bits.
    fn flush(&mut self) {
        if self.n > 0 {
            self.out.push(self.acc as u8);
            self.acc = 0;
            self.n = 0;
        }
    }
}

/// Hash chains over the input: `head[h]` the latest position whose next three bytes hash to
/// `h`, `prev[p]` the position before `p` with the same hash.
struct Matcher {
    head: Vec<u32>,
    prev: Vec<u32>,
}

impl Matcher {
    fn new(len: usize) -> Matcher {
        Matcher { head: vec![NO_POS; 1 << HASH_BITS], prev: vec![NO_POS; len] }
    }

    fn hash(b: &[u8]) -> usize {
        let v = u32::from(b[0]) | u32::from(b[1]) << 8 | u32::from(b[2]) << 16;
        (v.wrapping_mul(0x9E37_79B1) >> (32 - HASH_BITS)) as usize
    }

    fn insert(&mut self, data: &[u8], p: usize) {
        if p + MIN_MATCH <= data.len() {
            let h = Self::hash(&data[p..]);
            self.prev[p] = self.head[h];
            self.head[h] = p as u32;
        }
    }

    /// The longest match for position `p` among the chain of earlier positions: `(len, dist)`.
    fn longest(&self, data: &[u8], p: usize) -> (usize, usize) {
        let max = (data.len() - p).min(MAX_MATCH);
        if max < MIN_MATCH {
            return (0, 0);
        }
        let mut best = (0, 0);
        let mut cand = self.head[Self::hash(&data[p..])];
        let mut chain = 0;
        while cand != NO_POS && chain < MAX_CHAIN {
            let c = cand as usize;
            if p - c > WINDOW {
                break;
            }
            // Only a candidate that beats the best at its last byte can be longer.
            if data[c + best.0.min(max - 1)] == data[p + best.0.min(max - 1)] {
                let len = data[c..c + max].iter().zip(&data[p..p + max]).take_while(|(a, b)| a == b).count();
                if len > best.0 {
                    best = (len, p - c);
                    if len >= max.min(GOOD_ENOUGH) {
                        break;
                    }
                }
            }
            cand = self.prev[c];
            chain += 1;
        }
        if best.0 >= MIN_MATCH {
            best
        } else {
            (0, 0)
        }
    }

    /// Greedy LZ77: at every position the longest match if there is one, else a literal.
    fn encode(&mut self, data: &[u8], w: &mut BitWriter) {
        let mut p = 0;
        while p < data.len() {
            let (len, dist) = self.longest(data, p);
            if len >= MIN_MATCH {
                w.match_(len, dist);
                for q in p..p + len {
                    self.insert(data, q);
                }
                p += len;
            } else {
                w.literal_or_length(u32::from(data[p]));
                self.insert(data, p);
                p += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::inflate;
    use super::*;

    #[test]
    fn zlib_adler32_matches_known_values() {
        assert_eq!(adler32(b"Wikipedia"), 0x11E6_0398);
        assert_eq!(adler32(b""), 1);
    }

    #[test]
    fn zlib_stored_blocks_frame_the_data() {
        let data: Vec<u8> = (0..70_000u32).map(|i| (i * 7 % 251) as u8).collect();
        let z = stored(&data);
        // Two blocks: 65535 + 4465 bytes, each with a 5-byte header.
        assert_eq!(z.len(), 2 + 5 + 65535 + 5 + 4465 + 4);
        assert_eq!(z[2], 0);
        assert_eq!(&z[3..5], &65535u16.to_le_bytes());
        assert_eq!(z[2 + 5 + 65535], 1, "last block has BFINAL");
        let mut back = z[7..7 + 65535].to_vec();
        back.extend_from_slice(&z[7 + 65535 + 5..7 + 65535 + 5 + 4465]);
        assert_eq!(back, data);
        assert_eq!(inflate::zlib(&z).unwrap(), data);
    }

    /// Random bytes from the crate's generator.
    fn noise(n: usize, seed: u64) -> Vec<u8> {
        let mut rng = crate::rng::Rng::new(seed);
        (0..n).map(|_| rng.next_u64() as u8).collect()
    }

    #[test]
    fn zlib_compress_round_trips() {
        // Text-like repeats, long runs, matches at the window's edge, noise, tiny inputs.
        let mut cases: Vec<Vec<u8>> = vec![
            Vec::new(),
            b"a".to_vec(),
            b"abcabcabcabcabcabcabcabcabc".to_vec(),
            vec![0u8; 100_000],
            b"the quick brown fox jumps over the lazy dog. ".repeat(500),
            noise(20_000, 1),
        ];
        let mut far = noise(WINDOW, 2);
        far.extend_from_within(..300);
        cases.push(far);
        let mut mixed = Vec::new();
        for k in 0..200 {
            mixed.extend(noise(37 + k % 11, k as u64));
            mixed.extend(vec![(k % 7) as u8; k % 300]);
        }
        cases.push(mixed);
        for data in &cases {
            let z = compress(data);
            assert_eq!(inflate::zlib(&z).unwrap(), *data, "{} bytes", data.len());
            assert_eq!((u16::from(z[0]) << 8 | u16::from(z[1])) % 31, 0, "zlib header check");
        }
        // Runs and repeats shrink; noise falls back to stored blocks (never much larger).
        assert!(compress(&cases[3]).len() < 1_000);
        assert!(compress(&cases[4]).len() < cases[4].len() / 10);
        assert!(compress(&cases[5]).len() <= stored(&cases[5]).len());
    }
}

/// A small inflater (stored and fixed-Huffman blocks: what this module writes), so that the
/// tests check the streams against the format rather than against the writer.
#[cfg(test)]
pub(crate) mod inflate {
    use super::{adler32, DIST_BASE, DIST_EXTRA, LENGTH_BASE, LENGTH_EXTRA};
    use std::vec::Vec;

    struct Bits<'a> {
        data: &'a [u8],
        pos: usize,
    }

    impl Bits<'_> {
        fn bit(&mut self) -> Option<u32> {
            let b = (self.data.get(self.pos / 8)? >> (self.pos % 8)) & 1;
            self.pos += 1;
            Some(u32::from(b))
        }
        fn bits(&mut self, n: u8) -> Option<u32> {
            let mut v = 0;
            for i in 0..n {
                v |= self.bit()? << i;
            }
            Some(v)
        }
        /// Reads a Huffman code one bit at a time, most significant first.
        fn code(&mut self, n: u32) -> Option<u32> {
            let mut v = 0;
            for _ in 0..n {
                v = v << 1 | self.bit()?;
            }
            Some(v)
        }
        /// A symbol of the fixed literal/length code (codes of 7, 8 or 9 bits).
        fn literal_or_length(&mut self) -> Option<u32> {
            let v = self.code(7)?;
            if v <= 0x17 {
                return Some(256 + v);
            }
            let v = v << 1 | self.bit()?;
            match v {
                0x30..=0xBF => Some(v - 0x30),
                0xC0..=0xC7 => Some(280 + v - 0xC0),
                _ => Some(144 + (v << 1 | self.bit()?) - 0x190),
            }
        }
    }

    pub fn zlib(z: &[u8]) -> Option<Vec<u8>> {
        if z.len() < 6 || z[0] & 0x0F != 8 {
            return None;
        }
        let mut r = Bits { data: &z[2..z.len() - 4], pos: 0 };
        let mut out: Vec<u8> = Vec::new();
        loop {
            let last = r.bit()?;
            match r.bits(2)? {
                0 => {
                    r.pos = r.pos.div_ceil(8) * 8;
                    let len = r.bits(16)? as usize;
                    let nlen = r.bits(16)? as usize;
                    if len != !nlen & 0xFFFF {
                        return None;
                    }
                    let start = r.pos / 8;
                    out.extend_from_slice(r.data.get(start..start + len)?);
                    r.pos += 8 * len;
                }
                1 => loop {
                    let sym = r.literal_or_length()?;
                    match sym {
                        0..=255 => out.push(sym as u8),
                        256 => break,
                        257..=285 => {
                            let l = (sym - 257) as usize;
                            let len = LENGTH_BASE[l] as usize + r.bits(LENGTH_EXTRA[l])? as usize;
                            let d = r.code(5)? as usize;
                            let dist = *DIST_BASE.get(d)? as usize + r.bits(*DIST_EXTRA.get(d)?)? as usize;
                            let from = out.len().checked_sub(dist)?;
                            for k in 0..len {
                                out.push(out[from + k]);
                            }
                        }
                        _ => return None,
                    }
                },
                _ => return None,
            }
            if last == 1 {
                break;
            }
        }
        let sum = u32::from_be_bytes(z[z.len() - 4..].try_into().ok()?);
        (sum == adler32(&out)).then_some(out)
    }
}
