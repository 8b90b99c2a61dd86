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
    encode_frames(core::slice::from_ref(image), None)
}

/// The APNG file bytes of an animation: `frames` (all of the first one's size) shown
/// `fps` times a second, looping. Viewers without APNG support show the first frame.
///
/// # Errors
/// As [`encode`] for any frame; [`Error::Empty`] for no frames; [`Error::SizeMismatch`] for a
/// frame of another size than the first; [`Error::OutOfRange`] for 0 frames per second.
pub fn encode_animation(frames: &[Image], fps: u16) -> Result<Vec<u8>> {
    if fps == 0 {
        return Err(Error::OutOfRange { what: "animation frames per second", index: 0 });
    }
    encode_frames(frames, Some(fps))
}

/// PNG bytes of one frame (`fps` none) or an APNG of all of them.
fn encode_frames(frames: &[Image], fps: Option<u16>) -> Result<Vec<u8>> {
    let first = frames.first().ok_or(Error::Empty { what: "PNG animation frames" })?;
    if first.width == 0 || first.height == 0 {
        return Err(Error::Empty { what: "PNG image" });
    }
    let expected = first.width * first.height * 3;
    for image in frames {
        if (image.width, image.height) != (first.width, first.height) {
            return Err(Error::SizeMismatch {
                what: "PNG animation frame width",
                expected: first.width,
                got: image.width,
            });
        }
        if image.rgb.len() != expected {
            return Err(Error::SizeMismatch { what: "PNG image's RGB bytes", expected, got: image.rgb.len() });
        }
    }
    let failed = |e: png::EncodingError| Error::Io { path: "PNG encoder".to_string(), message: e.to_string() };
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, first.width as u32, first.height as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::High);
    if let Some(fps) = fps {
        let count =
            u32::try_from(frames.len()).map_err(|_| Error::OutOfRange { what: "animation frames", index: 0 })?;
        // Loops forever (0 plays: no end).
        encoder.set_animated(count, 0).map_err(failed)?;
        encoder.set_frame_delay(1, fps).map_err(failed)?;
    }
    let mut writer = encoder.write_header().map_err(failed)?;
    for image in frames {
        writer.write_image_data(&image.rgb).map_err(failed)?;
    }
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

/// Writes an animation as APNG (see [`encode_animation`]).
///
/// # Errors
/// [`Error::Io`] naming `path`; the errors of [`encode_animation`].
pub fn write_animation(path: impl AsRef<Path>, frames: &[Image], fps: u16) -> Result<()> {
    let p = path.as_ref();
    std::fs::write(p, encode_animation(frames, fps)?).map_err(|e| Error::io(p, e))
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

    #[test]
    fn png_animation_decodes_frame_by_frame_at_its_rate() {
        let frames: Vec<Image> = (0..4u8).map(|k| Image::new(5, 3, [40 * k, 255 - 30 * k, 9])).collect();
        let bytes = encode_animation(&frames, 15).unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(&bytes[..])).read_info().unwrap();
        let control = reader.info().animation_control.expect("an acTL chunk");
        assert_eq!((control.num_frames, control.num_plays), (4, 0));
        let mut buf = std::vec![0u8; reader.output_buffer_size().unwrap()];
        for (k, frame) in frames.iter().enumerate() {
            reader.next_frame(&mut buf).unwrap();
            let fc = reader.info().frame_control.expect("an fcTL chunk per frame");
            assert_eq!((fc.delay_num, fc.delay_den), (1, 15), "frame {k}");
            assert_eq!(&buf[..frame.rgb.len()], &frame.rgb[..], "frame {k}");
        }
        // A viewer without APNG support sees the first frame.
        assert_eq!(decode(&bytes).unwrap().rgb, frames[0].rgb);
        assert!(matches!(encode_animation(&[], 15), Err(Error::Empty { .. })));
        assert!(matches!(encode_animation(&frames, 0), Err(Error::OutOfRange { .. })));
        let ragged = [Image::new(5, 3, [0; 3]), Image::new(4, 3, [0; 3])];
        assert!(matches!(encode_animation(&ragged, 15), Err(Error::SizeMismatch { .. })));
    }
}
