//! PNG output (8-bit RGB, through the `png` crate) and a helper writing several preview frames
//! side by side as one strip.

use crate::error::{Error, Result};
use crate::render::Image;
use std::path::Path;
use std::string::ToString;
use std::vec::Vec;

/// The PNG file bytes of an image (8-bit RGB, adaptive row filters, high compression).
///
/// # Errors
/// [`Error::Empty`] for an image without pixels (PNG has none),
/// [`Error::SizeMismatch`] when `image.rgb` does not hold `3 · width · height` bytes.
pub fn encode(image: &Image) -> Result<Vec<u8>> {
    if image.width == 0 || image.height == 0 {
        return Err(Error::Empty { what: "PNG image" });
    }
    let expected = image.width * image.height * 3;
    if image.rgb.len() != expected {
        return Err(Error::SizeMismatch { what: "PNG image's RGB bytes", expected, got: image.rgb.len() });
    }
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, image.width as u32, image.height as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::High);
    let failed = |e: png::EncodingError| Error::Io { path: "PNG encoder".to_string(), message: e.to_string() };
    let mut writer = encoder.write_header().map_err(failed)?;
    writer.write_image_data(&image.rgb).map_err(failed)?;
    writer.finish().map_err(failed)?;
    Ok(out)
}

/// Writes an image as PNG.
///
/// # Errors
/// [`Error::Io`] naming `path`; the errors of [`encode`].
pub fn write(path: impl AsRef<Path>, image: &Image) -> Result<()> {
    let p = path.as_ref();
    std::fs::write(p, encode(image)?).map_err(|e| Error::io(p, e))
}

/// Writes frames side by side as one PNG strip.
///
/// # Errors
/// As [`write()`]; [`Error::Empty`] when there are no frames.
pub fn write_strip(path: impl AsRef<Path>, frames: &[Image]) -> Result<()> {
    write(path, &Image::side_by_side(frames))
}

/// Reads an 8-bit RGB or RGBA PNG back into an [`Image`] (alpha dropped).
///
/// # Errors
/// [`Error::Parse`] (format `"png"`) for a file that is not such a PNG.
pub fn decode(bytes: &[u8]) -> Result<Image> {
    let bad = |e: &dyn core::fmt::Display| Error::parse("png", 0, e.to_string());
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().map_err(|e| bad(&e))?;
    let size = reader.output_buffer_size().ok_or_else(|| bad(&"image too large"))?;
    let mut buf = std::vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(|e| bad(&e))?;
    let channels = match (info.color_type, info.bit_depth) {
        (png::ColorType::Rgb, png::BitDepth::Eight) => 3,
        (png::ColorType::Rgba, png::BitDepth::Eight) => 4,
        _ => return Err(bad(&"not 8-bit RGB or RGBA")),
    };
    let (width, height) = (info.width as usize, info.height as usize);
    let mut image = Image::new(width, height, [0, 0, 0]);
    for y in 0..height {
        let row = &buf[y * info.line_size..y * info.line_size + width * channels];
        for (x, px) in row.chunks_exact(channels).enumerate() {
            image.rgb[(y * width + x) * 3..(y * width + x) * 3 + 3].copy_from_slice(&px[..3]);
        }
    }
    Ok(image)
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let bytes = encode(&im).unwrap();
        assert_eq!(&bytes[..8], &[0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1A, b'\n']);
        let back = decode(&bytes).unwrap();
        assert_eq!((back.width, back.height), (w, h));
        assert_eq!(back.rgb, im.rgb);
        let raw_size = (w * 3 + 1) * h;
        assert!(bytes.len() < raw_size / 2, "{} bytes for {raw_size} raw", bytes.len());
    }

    #[test]
    fn png_writes_a_strip_that_decodes() {
        let dir = std::env::temp_dir().join(std::format!("hood-png-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let frames = [Image::new(3, 2, [10, 20, 30]), Image::new(4, 2, [200, 0, 7])];
        let path = dir.join("strip.png");
        write_strip(&path, &frames).unwrap();
        let back = decode(&std::fs::read(&path).unwrap()).unwrap();
        assert_eq!(back.rgb, Image::side_by_side(&frames).rgb);
        assert!(decode(b"not a png").is_err());
        assert!(matches!(write_strip(&path, &[]), Err(Error::Empty { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
