//! A PNG writer (8-bit RGB, no interlace: each row filtered by the filter that makes it
//! smallest by the usual heuristic, then compressed by [`super::zlib`]) with its own CRC-32, and
//! a helper writing several preview frames side by side as one strip.

use super::zlib;
use crate::error::{Error, Result};
use crate::render::Image;
use std::path::Path;

use std::vec;
use std::vec::Vec;

pub use crate::checksum::crc32;

fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// The PNG file bytes of an image.
pub fn encode(image: &Image) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&[0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1A, b'\n']);
    let mut ihdr = Vec::with_capacity(13);
    ihdr.extend_from_slice(&(image.width as u32).to_be_bytes());
    ihdr.extend_from_slice(&(image.height as u32).to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8 bits, RGB, deflate, filter method 0 (five row filters), no interlace
    chunk(&mut out, b"IHDR", &ihdr);
    chunk(&mut out, b"IDAT", &zlib::compress(&filtered(image)));
    chunk(&mut out, b"IEND", &[]);
    out
}

/// Bytes per pixel (RGB, 8 bits): the left neighbour of the filters.
const BPP: usize = 3;

/// The image's rows, each led by its filter type and filtered by it (PNG filters 0-4: none,
/// sub, up, average, Paeth), the filter chosen per row as the one with the smallest sum of
/// absolute values of its output taken as signed bytes.
fn filtered(image: &Image) -> Vec<u8> {
    let row = image.width * 3;
    let mut raw = Vec::with_capacity((row + 1) * image.height);
    let zeros = vec![0u8; row];
    let mut candidate = vec![0u8; row];
    let mut best = vec![0u8; row];
    for y in 0..image.height {
        let cur = &image.rgb[y * row..(y + 1) * row];
        let up = if y == 0 { &zeros[..] } else { &image.rgb[(y - 1) * row..y * row] };
        let mut best_kind = 0;
        let mut best_cost = u64::MAX;
        for kind in 0..5u8 {
            for i in 0..row {
                let a = if i >= BPP { cur[i - BPP] } else { 0 };
                let c = if i >= BPP { up[i - BPP] } else { 0 };
                candidate[i] = cur[i].wrapping_sub(predict(kind, a, up[i], c));
            }
            let cost = candidate.iter().map(|&v| u64::from((v as i8).unsigned_abs())).sum::<u64>();
            if cost < best_cost {
                best_cost = cost;
                best_kind = kind;
                best.copy_from_slice(&candidate);
            }
        }
        raw.push(best_kind);
        raw.extend_from_slice(&best);
    }
    raw
}

/// The prediction of PNG filter `kind` from the left (`a`), upper (`b`) and upper-left (`c`)
/// bytes.
fn predict(kind: u8, a: u8, b: u8, c: u8) -> u8 {
    match kind {
        1 => a,
        2 => b,
        3 => ((u16::from(a) + u16::from(b)) / 2) as u8,
        4 => {
            let p = i16::from(a) + i16::from(b) - i16::from(c);
            let (pa, pb, pc) = ((p - i16::from(a)).abs(), (p - i16::from(b)).abs(), (p - i16::from(c)).abs());
            if pa <= pb && pa <= pc {
                a
            } else if pb <= pc {
                b
            } else {
                c
            }
        }
        _ => 0,
    }
}

/// Writes an image as PNG.
pub fn write(path: impl AsRef<Path>, image: &Image) -> Result<()> {
    let p = path.as_ref();
    std::fs::write(p, encode(image)).map_err(|e| Error::io(p, e))
}

/// Writes frames side by side as one PNG strip.
pub fn write_strip(path: impl AsRef<Path>, frames: &[Image]) -> Result<()> {
    write(path, &Image::side_by_side(frames))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_encodes_a_small_image() {
        let mut im = Image::new(3, 2, [10, 20, 30]);
        im.rgb[0] = 255;
        let bytes = encode(&im);
        assert_eq!(&bytes[..8], &[0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1A, b'\n']);
        assert_eq!(&bytes[12..16], b"IHDR");
        assert_eq!(u32::from_be_bytes(bytes[16..20].try_into().unwrap()), 3);
        assert_eq!(u32::from_be_bytes(bytes[20..24].try_into().unwrap()), 2);
        // IHDR CRC covers type + data.
        assert_eq!(u32::from_be_bytes(bytes[29..33].try_into().unwrap()), crc32(&bytes[12..29]));
        assert_eq!(&bytes[bytes.len() - 8..bytes.len() - 4], b"IEND");
    }

    /// The pixels back from a PNG this module wrote: inflate the IDAT chunk, undo the filters.
    /// Also returns the filter type of every row.
    fn decode(bytes: &[u8]) -> (usize, usize, Vec<u8>, Vec<u8>) {
        let width = u32::from_be_bytes(bytes[16..20].try_into().unwrap()) as usize;
        let height = u32::from_be_bytes(bytes[20..24].try_into().unwrap()) as usize;
        let idat_len = u32::from_be_bytes(bytes[33..37].try_into().unwrap()) as usize;
        assert_eq!(&bytes[37..41], b"IDAT");
        assert_eq!(
            u32::from_be_bytes(bytes[41 + idat_len..45 + idat_len].try_into().unwrap()),
            crc32(&bytes[37..41 + idat_len])
        );
        let raw = crate::io::zlib::inflate::zlib(&bytes[41..41 + idat_len]).expect("a valid zlib stream");
        let row = width * 3;
        assert_eq!(raw.len(), height * (row + 1));
        let mut rgb = vec![0u8; row * height];
        let kinds: Vec<u8> = (0..height).map(|y| raw[y * (row + 1)]).collect();
        for (y, &kind) in kinds.iter().enumerate() {
            assert!(kind <= 4);
            for i in 0..row {
                let a = if i >= BPP { rgb[y * row + i - BPP] } else { 0 };
                let b = if y > 0 { rgb[(y - 1) * row + i] } else { 0 };
                let c = if y > 0 && i >= BPP { rgb[(y - 1) * row + i - BPP] } else { 0 };
                rgb[y * row + i] = raw[y * (row + 1) + 1 + i].wrapping_add(predict(kind, a, b, c));
            }
        }
        (width, height, rgb, kinds)
    }

    #[test]
    fn png_round_trips_and_compresses_a_rendering() {
        // A rendering-like image: flat background, a shaded disc, a gradient band, some noise.
        let (w, h) = (97, 61);
        let mut im = Image::new(w, h, [245, 245, 240]);
        let mut rng = crate::rng::Rng::new(1);
        for y in 0..h {
            for x in 0..w {
                let p = &mut im.rgb[(y * w + x) * 3..(y * w + x) * 3 + 3];
                let (dx, dy) = (x as f32 - 40.0, y as f32 - 30.0);
                if dx * dx + dy * dy < 400.0 {
                    p.copy_from_slice(&[60, 110, (150.0 + dx * 2.0) as u8]);
                } else if y > 50 {
                    p.copy_from_slice(&[(x * 2) as u8, (y * 3) as u8, 128]);
                } else if x > 85 {
                    p.copy_from_slice(&rng.next_u64().to_le_bytes()[..3]);
                }
            }
        }
        let bytes = encode(&im);
        let (dw, dh, rgb, kinds) = decode(&bytes);
        assert_eq!((dw, dh), (w, h));
        assert_eq!(rgb, im.rgb);
        let raw_size = (w * 3 + 1) * h;
        assert!(bytes.len() < raw_size / 2, "{} bytes for {raw_size} raw", bytes.len());
        // Every filter kind decodes: noise makes the heuristic pick several.
        let used: std::collections::BTreeSet<u8> = kinds.into_iter().collect();
        assert!(used.len() >= 2, "filters used: {used:?}");
    }
}
