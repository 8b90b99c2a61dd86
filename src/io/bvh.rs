//! BVH motion capture reader: `HIERARCHY` (joints, offsets, channels in any order, end sites)
//! and `MOTION` (frame count, frame time, one line of channel values per frame). Rotations are
//! degrees; a joint's rotation channels compose left to right in the order listed (`Zrotation
//! Yrotation Xrotation` gives `Rz * Ry * Rx`); position channels add to the joint's offset.
//! Lengths stay in the file's units.

use crate::error::{Error, Result};
use crate::rig::motion::{Clip, ClipJoint};
use alloc::format;
use alloc::string::{String, ToString};
use alloc::vec::Vec;
use glam::{Quat, Vec3};

#[derive(Clone, Copy, Debug, PartialEq)]
enum Channel {
    Pos(usize),
    Rot(usize),
}

fn err(line: usize, msg: impl Into<String>) -> Error {
    Error::parse("bvh", line, msg)
}

/// Whitespace tokens of the hierarchy with their 1-based line numbers.
struct Tokens<'a> {
    toks: Vec<(&'a str, usize)>,
    i: usize,
    last_line: usize,
}

impl<'a> Tokens<'a> {
    fn next(&mut self) -> Result<(&'a str, usize)> {
        let t = self.toks.get(self.i).copied().ok_or_else(|| err(self.last_line, "unexpected end of file"))?;
        self.i += 1;
        Ok(t)
    }
    fn expect(&mut self, word: &str) -> Result<usize> {
        let (t, l) = self.next()?;
        if t.eq_ignore_ascii_case(word) {
            Ok(l)
        } else {
            Err(err(l, format!("expected '{word}', found '{t}'")))
        }
    }
    fn number(&mut self) -> Result<f32> {
        let (t, l) = self.next()?;
        let v: f32 = t.parse().map_err(|_| err(l, format!("expected a number, found '{t}'")))?;
        if !v.is_finite() {
            return Err(err(l, "number is not finite"));
        }
        Ok(v)
    }
    fn vec3(&mut self) -> Result<[f32; 3]> {
        Ok([self.number()?, self.number()?, self.number()?])
    }
}

struct Hierarchy {
    joints: Vec<ClipJoint>,
    channels: Vec<Vec<Channel>>,
}

fn parse_joint(t: &mut Tokens, h: &mut Hierarchy, parent: Option<usize>, depth: usize) -> Result<()> {
    let (name, line) = t.next()?;
    if depth > 256 {
        return Err(err(line, "hierarchy nested too deeply"));
    }
    if name == "{" {
        return Err(err(line, "joint without a name"));
    }
    let me = h.joints.len();
    h.joints.push(ClipJoint { name: name.to_string(), parent, offset: [0.0; 3], end_site: None });
    h.channels.push(Vec::new());
    t.expect("{")?;
    t.expect("OFFSET")?;
    h.joints[me].offset = t.vec3()?;
    let (word, l) = t.next()?;
    if !word.eq_ignore_ascii_case("CHANNELS") {
        return Err(err(l, format!("expected 'CHANNELS' for joint '{name}', found '{word}'")));
    }
    let (count, l) = t.next()?;
    let count: usize = count.parse().map_err(|_| err(l, format!("bad channel count '{count}'")))?;
    if count > 6 {
        return Err(err(l, format!("{count} channels (at most 6)")));
    }
    for _ in 0..count {
        let (c, l) = t.next()?;
        let ch = match c.to_ascii_lowercase().as_str() {
            "xposition" => Channel::Pos(0),
            "yposition" => Channel::Pos(1),
            "zposition" => Channel::Pos(2),
            "xrotation" => Channel::Rot(0),
            "yrotation" => Channel::Rot(1),
            "zrotation" => Channel::Rot(2),
            _ => return Err(err(l, format!("unknown channel '{c}' (declared {count} channels?)"))),
        };
        if h.channels[me].contains(&ch) {
            return Err(err(l, format!("channel '{c}' repeated")));
        }
        h.channels[me].push(ch);
    }
    loop {
        let (word, l) = t.next()?;
        if word == "}" {
            return Ok(());
        } else if word.eq_ignore_ascii_case("JOINT") {
            parse_joint(t, h, Some(me), depth + 1)?;
        } else if word.eq_ignore_ascii_case("End") {
            t.expect("Site")?;
            t.expect("{")?;
            t.expect("OFFSET")?;
            let e = t.vec3()?;
            t.expect("}")?;
            if h.joints[me].end_site.replace(e).is_some() {
                return Err(err(l, "second End Site in one joint"));
            }
        } else {
            return Err(err(l, format!("expected 'JOINT', 'End Site' or '}}', found '{word}'")));
        }
    }
}

/// Parses a BVH document into a [`Clip`] (lengths in the file's units).
///
/// # Errors
/// [`Error::Parse`] with format `"bvh"` and the 1-based line: missing sections, unknown
/// channels, bad numbers, unbalanced braces, a frame line with the wrong number of values,
/// fewer frames than declared, a frame time that is not positive; [`Error::CapacityExceeded`]
/// for more joint samples than [`crate::limits::MAX_MOTION_SAMPLES`].
pub fn parse(text: &str) -> Result<Clip> {
    let lines: Vec<&str> = text.lines().collect();
    let motion_line = lines
        .iter()
        .position(|l| l.trim().eq_ignore_ascii_case("MOTION"))
        .ok_or_else(|| err(lines.len(), "no MOTION section"))?;
    let mut toks = Vec::new();
    for (i, l) in lines[..motion_line].iter().enumerate() {
        for w in l.split_whitespace() {
            toks.push((w, i + 1));
        }
    }
    let mut t = Tokens { toks, i: 0, last_line: motion_line + 1 };
    let l = t.expect("HIERARCHY")?;
    let _ = l;
    t.expect("ROOT")?;
    let mut h = Hierarchy { joints: Vec::new(), channels: Vec::new() };
    parse_joint(&mut t, &mut h, None, 0)?;
    if let Some(&(w, l)) = t.toks.get(t.i) {
        return Err(err(l, format!("unexpected '{w}' after the root joint (only one ROOT is supported)")));
    }
    // MOTION header.
    let header = |k: usize, key: &str| -> Result<&str> {
        let l = lines.get(k).ok_or_else(|| err(k, format!("missing '{key}' line")))?;
        let tl = l.trim();
        let rest = tl
            .strip_prefix(key)
            .or_else(|| tl.get(..key.len()).filter(|p| p.eq_ignore_ascii_case(key)).map(|_| &tl[key.len()..]))
            .ok_or_else(|| err(k + 1, format!("expected '{key}', found '{tl}'")))?;
        Ok(rest.trim())
    };
    let frames_text = header(motion_line + 1, "Frames:")?;
    let n_frames: usize =
        frames_text.parse().map_err(|_| err(motion_line + 2, format!("bad frame count '{frames_text}'")))?;
    if n_frames == 0 {
        return Err(err(motion_line + 2, "no frames"));
    }
    let time_text = header(motion_line + 2, "Frame Time:")?;
    let frame_time: f32 =
        time_text.parse().map_err(|_| err(motion_line + 3, format!("bad frame time '{time_text}'")))?;
    if !(frame_time > 0.0 && frame_time.is_finite()) {
        return Err(err(motion_line + 3, format!("frame time {frame_time} is not positive")));
    }
    // Every frame needs a line of its own: what is reserved is bounded by the lines that follow,
    // not by the count declared (a short file declaring 10^8 frames is refused in the loop below).
    let frame_lines = lines.len().saturating_sub(motion_line + 3);
    let nj = h.joints.len();
    let samples = n_frames.min(frame_lines).saturating_mul(nj);
    crate::limits::within("bvh joint samples (frames x joints)", samples, crate::limits::MAX_MOTION_SAMPLES)?;
    let n_channels: usize = h.channels.iter().map(Vec::len).sum();
    let mut rotations = Vec::with_capacity(samples);
    let mut translations = Vec::with_capacity(samples);
    let mut values: Vec<f32> = Vec::with_capacity(n_channels);
    let mut k = motion_line + 3;
    for f in 0..n_frames {
        // Skip blank lines between frames.
        while k < lines.len() && lines[k].trim().is_empty() {
            k += 1;
        }
        let line = *lines.get(k).ok_or_else(|| err(k + 1, format!("{n_frames} frames declared, {f} found")))?;
        values.clear();
        for w in line.split_whitespace() {
            let v: f32 = w.parse().map_err(|_| err(k + 1, format!("bad number '{w}'")))?;
            if !v.is_finite() {
                return Err(err(k + 1, "value is not finite"));
            }
            values.push(v);
        }
        if values.len() != n_channels {
            return Err(err(
                k + 1,
                format!("frame {f} has {} values, the hierarchy has {n_channels} channels", values.len()),
            ));
        }
        let mut c = 0;
        for j in 0..nj {
            let mut q = Quat::IDENTITY;
            let mut p = Vec3::from(h.joints[j].offset);
            for &ch in &h.channels[j] {
                let v = values[c];
                c += 1;
                match ch {
                    Channel::Pos(a) => p[a] += v,
                    Channel::Rot(a) => {
                        let r = v.to_radians();
                        q *= match a {
                            0 => Quat::from_rotation_x(r),
                            1 => Quat::from_rotation_y(r),
                            _ => Quat::from_rotation_z(r),
                        };
                    }
                }
            }
            rotations.push(q.normalize());
            translations.push(p);
        }
        k += 1;
    }
    if let Some(extra) = lines[k.min(lines.len())..].iter().position(|l| !l.trim().is_empty()) {
        return Err(err(k + extra + 1, format!("more frame lines than the {n_frames} declared")));
    }
    Clip::new(h.joints, frame_time, rotations, translations)
}

/// Reads a BVH file (see [`parse`]).
pub fn read(path: impl AsRef<std::path::Path>) -> Result<Clip> {
    let p = path.as_ref();
    let text = std::fs::read_to_string(p).map_err(|e| Error::io(p, e))?;
    parse(&text)
}

#[cfg(test)]
mod tests;
