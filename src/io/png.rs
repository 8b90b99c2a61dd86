//! A PNG writer (8-bit RGB, no interlace) with its own zlib stream (stored deflate blocks),
//! CRC-32 and Adler-32, and a helper writing several preview frames side by side as one strip.

use crate::error::{Error, Result};
use crate::render::Image;
use std::path::Path;
use std::string::ToString;
use std::vec::Vec;

/// CRC-32 (IEEE 802.3, reflected, polynomial 0xEDB88320) as PNG chunks use.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

/// Adler-32 as zlib streams end with.
pub fn adler32(bytes: &[u8]) -> u32 {
    let (mut a, mut b) = (1u32, 0u32);
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
pub fn zlib_stored(data: &[u8]) -> Vec<u8> {
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
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8 bits, RGB, deflate, no filter choice, no interlace
    chunk(&mut out, b"IHDR", &ihdr);
    let row = image.width * 3;
    let mut raw = Vec::with_capacity((row + 1) * image.height);
    for y in 0..image.height {
        raw.push(0); // filter: none
        raw.extend_from_slice(&image.rgb[y * row..(y + 1) * row]);
    }
    chunk(&mut out, b"IDAT", &zlib_stored(&raw));
    chunk(&mut out, b"IEND", &[]);
    out
}

/// Writes an image as PNG.
pub fn write(path: impl AsRef<Path>, image: &Image) -> Result<()> {
    let p = path.as_ref();
    std::fs::write(p, encode(image)).map_err(|e| Error::Io { path: p.display().to_string(), message: e.to_string() })
}

/// Writes frames side by side as one PNG strip.
pub fn write_strip(path: impl AsRef<Path>, frames: &[Image]) -> Result<()> {
    write(path, &Image::side_by_side(frames))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_checksums_match_known_values() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(adler32(b"Wikipedia"), 0x11E6_0398);
        assert_eq!(crc32(b"IEND"), 0xAE42_6082);
    }

    #[test]
    fn png_stored_zlib_blocks_frame_the_data() {
        let data: Vec<u8> = (0..70_000u32).map(|i| (i * 7 % 251) as u8).collect();
        let z = zlib_stored(&data);
        // Two blocks: 65535 + 4465 bytes, each with a 5-byte header.
        assert_eq!(z.len(), 2 + 5 + 65535 + 5 + 4465 + 4);
        assert_eq!(z[2], 0);
        assert_eq!(&z[3..5], &65535u16.to_le_bytes());
        assert_eq!(z[2 + 5 + 65535], 1, "last block has BFINAL");
        // Reassemble.
        let mut back = z[7..7 + 65535].to_vec();
        back.extend_from_slice(&z[7 + 65535 + 5..7 + 65535 + 5 + 4465]);
        assert_eq!(back, data);
    }

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
}
