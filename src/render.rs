//! A small software rasteriser for previews (feature `tools`): z-buffered triangles with flat
//! Lambert shading, an orthographic or perspective look-at camera, RGB images that can be laid side
//! by side. Write them with [`crate::io::png`].

use alloc::vec;
use alloc::vec::Vec;
use glam::Vec3;

/// How the camera projects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Parallel projection; the image shows `2 * half_height` metres vertically.
    Orthographic {
        /// Half the visible height, metres.
        half_height: f32,
    },
    /// Pinhole projection with a vertical field of view (radians).
    Perspective {
        /// Vertical field of view, radians.
        fov_y: f32,
    },
}

/// A look-at camera (metres, world frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: [f32; 3],
    /// Point looked at (the image centre).
    pub target: [f32; 3],
    /// Up direction (usually +y).
    pub up: [f32; 3],
    /// Projection.
    pub projection: Projection,
}

impl Camera {
    /// An orthographic camera looking at `target` from direction `from` (e.g. +z: from the
    /// front of a body facing +z), showing `height` metres vertically.
    pub fn orthographic(target: [f32; 3], from: [f32; 3], height: f32) -> Camera {
        let t = Vec3::from(target);
        let eye = t + Vec3::from(from).normalize_or(Vec3::Z) * 10.0;
        Camera {
            eye: eye.into(),
            target,
            up: [0.0, 1.0, 0.0],
            projection: Projection::Orthographic { half_height: 0.5 * height },
        }
    }
}

/// An RGB image with a depth buffer.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Row-major RGB, top row first.
    pub rgb: Vec<u8>,
    depth: Vec<f32>,
}

/// Shading of one mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Style {
    /// Base colour.
    pub colour: [u8; 3],
}

impl Image {
    /// A `width x height` image filled with `background`.
    pub fn new(width: usize, height: usize, background: [u8; 3]) -> Image {
        let mut rgb = Vec::with_capacity(width * height * 3);
        for _ in 0..width * height {
            rgb.extend_from_slice(&background);
        }
        Image { width, height, rgb, depth: vec![f32::INFINITY; width * height] }
    }

    /// Draws a horizontal line of the floor (y = `floor_y`) as a thin grey band, by rasterising
    /// a large quad.
    pub fn draw_floor(&mut self, camera: &Camera, centre: [f32; 3], size: f32, floor_y: f32) {
        let c = Vec3::from(centre);
        let h = 0.5 * size;
        let q = [
            [c.x - h, floor_y, c.z - h],
            [c.x + h, floor_y, c.z - h],
            [c.x + h, floor_y, c.z + h],
            [c.x - h, floor_y, c.z + h],
        ];
        self.draw_mesh(camera, &q, &[[0, 2, 1], [0, 3, 2]], Style { colour: [200, 200, 190] });
    }

    /// Draws triangles with flat Lambert shading (light from the upper front-left of the
    /// camera; both sides lit, back faces a little darker) into the image and depth buffer.
    pub fn draw_mesh(&mut self, camera: &Camera, positions: &[[f32; 3]], faces: &[[u32; 3]], style: Style) {
        let eye = Vec3::from(camera.eye);
        let fwd = (Vec3::from(camera.target) - eye).normalize_or(Vec3::NEG_Z);
        let right = fwd.cross(Vec3::from(camera.up)).normalize_or(Vec3::X);
        let up = right.cross(fwd);
        let (w, h) = (self.width as f32, self.height as f32);
        let light = (up * 0.6 - right * 0.4 - fwd * 0.7).normalize();
        let project = |p: Vec3| -> Option<Vec3> {
            let d = p - eye;
            let (x, y, z) = (d.dot(right), d.dot(up), d.dot(fwd));
            match camera.projection {
                Projection::Orthographic { half_height } => {
                    let s = 0.5 * h / half_height;
                    Some(Vec3::new(0.5 * w + x * s, 0.5 * h - y * s, z))
                }
                Projection::Perspective { fov_y } => {
                    if z <= 1e-3 {
                        return None;
                    }
                    let f = 0.5 * h / libm::tanf(0.5 * fov_y);
                    Some(Vec3::new(0.5 * w + f * x / z, 0.5 * h - f * y / z, z))
                }
            }
        };
        for face in faces {
            let p = face.map(|i| Vec3::from(positions[i as usize]));
            let n = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
            let facing = n.dot(-fwd);
            let lambert = n.dot(light).abs();
            let shade = (0.3 + 0.7 * lambert) * if facing < 0.0 { 0.75 } else { 1.0 };
            let colour = style.colour.map(|c| (c as f32 * shade).clamp(0.0, 255.0) as u8);
            let (Some(a), Some(b), Some(c)) = (project(p[0]), project(p[1]), project(p[2])) else { continue };
            self.fill_triangle(a, b, c, colour);
        }
    }

    fn fill_triangle(&mut self, a: Vec3, b: Vec3, c: Vec3, colour: [u8; 3]) {
        let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
        if area.abs() < 1e-12 {
            return;
        }
        let x0 = libm::floorf(a.x.min(b.x).min(c.x)).max(0.0) as usize;
        let x1 = (libm::ceilf(a.x.max(b.x).max(c.x)) as isize).min(self.width as isize - 1);
        let y0 = libm::floorf(a.y.min(b.y).min(c.y)).max(0.0) as usize;
        let y1 = (libm::ceilf(a.y.max(b.y).max(c.y)) as isize).min(self.height as isize - 1);
        if x1 < 0 || y1 < 0 {
            return;
        }
        for y in y0..=y1 as usize {
            for x in x0..=x1 as usize {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                let w0 = ((b.x - px) * (c.y - py) - (b.y - py) * (c.x - px)) / area;
                let w1 = ((c.x - px) * (a.y - py) - (c.y - py) * (a.x - px)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * a.z + w1 * b.z + w2 * c.z;
                let k = y * self.width + x;
                if z < self.depth[k] {
                    self.depth[k] = z;
                    self.rgb[3 * k..3 * k + 3].copy_from_slice(&colour);
                }
            }
        }
    }

    /// The images side by side (top-aligned, the background of the first filling gaps).
    pub fn side_by_side(images: &[Image]) -> Image {
        let width = images.iter().map(|i| i.width).sum();
        let height = images.iter().map(|i| i.height).max().unwrap_or(0);
        let bg = images.first().map_or([255; 3], |i| [i.rgb[0], i.rgb[1], i.rgb[2]]);
        let mut out = Image::new(width, height, bg);
        let mut x0 = 0;
        for im in images {
            for y in 0..im.height {
                let src = &im.rgb[3 * y * im.width..3 * (y + 1) * im.width];
                let d = 3 * (y * width + x0);
                out.rgb[d..d + src.len()].copy_from_slice(src);
            }
            x0 += im.width;
        }
        out
    }
}
