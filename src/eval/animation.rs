//! What a rollout plays: the [`Animation`] trait (garment, body frames, pinned targets, initial
//! state), implemented by [`Scene`] and by the owned, editable [`Playback`].

use crate::body::BodyMesh;
use crate::error::{Error, Result};
use crate::mesh::Garment;
use crate::scene::Scene;
use alloc::vec;
use alloc::vec::Vec;

/// What a rollout plays: a garment, the body's frames (30 Hz), the pinned vertices' targets per
/// frame and the garment's initial positions.
pub trait Animation {
    /// The garment (rest shape, materials, pinned flags).
    fn garment(&self) -> &Garment;
    /// The body's topology, if there is a body.
    fn body_mesh(&self) -> Option<&BodyMesh>;
    /// Number of frames (frame 0 is the initial one).
    fn n_frames(&self) -> usize;
    /// Body positions at frame `f` (m; clamped to the last frame; empty without a body).
    fn body_frame(&self, f: usize) -> &[[f32; 3]];
    /// Targets of the pinned vertices at frame `f` into `out` (one entry per garment vertex, m).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `out` is not one entry per garment vertex.
    fn pin_targets(&self, f: usize, out: &mut [[f32; 3]]) -> Result<()>;
    /// Garment positions at frame 0, m.
    ///
    /// # Errors
    /// Implementation-specific (body queries, ...).
    fn initial_garment(&self) -> Result<Vec<[f32; 3]>>;
    /// Whether [`Animation::pin_targets`] gives every vertex where the body carries it (the
    /// garment skinned with the body), not only fixed targets for the pinned ones: then the
    /// off-body metric measures the garment's shift ([`OffBodyFrame::shift`]). Default: no.
    ///
    /// [`OffBodyFrame::shift`]: super::OffBodyFrame::shift
    fn skins_garment(&self) -> bool {
        false
    }
    /// Garment velocities at frame 0, m per frame (the displacement since the frame before):
    /// the motion the body carries the garment with when the animation starts in mid-motion.
    /// Default: at rest.
    ///
    /// # Errors
    /// Implementation-specific (skinning, ...).
    fn initial_velocity(&self) -> Result<Vec<[f32; 3]>> {
        Ok(vec![[0.0; 3]; self.garment().n_vertices()])
    }
}

impl Animation for Scene {
    fn garment(&self) -> &Garment {
        &self.garment
    }
    fn body_mesh(&self) -> Option<&BodyMesh> {
        Some(&self.body)
    }
    fn n_frames(&self) -> usize {
        Scene::n_frames(self)
    }
    fn body_frame(&self, f: usize) -> &[[f32; 3]] {
        Scene::body_frame(self, f)
    }
    fn pin_targets(&self, f: usize, out: &mut [[f32; 3]]) -> Result<()> {
        self.skinned_garment(f, out)
    }
    fn initial_garment(&self) -> Result<Vec<[f32; 3]>> {
        Scene::initial_garment(self, 0)
    }
    fn skins_garment(&self) -> bool {
        true
    }
    fn initial_velocity(&self) -> Result<Vec<[f32; 3]>> {
        Scene::initial_velocity(self, 0)
    }
}

/// An animation held in memory, every part editable (for hard cases: a body that jumps, a bad
/// start state) and buildable from files.
#[derive(Clone, Debug)]
pub struct Playback {
    /// The garment.
    pub garment: Garment,
    /// Body topology (`None`: no body).
    pub body: Option<BodyMesh>,
    /// Body positions per frame, m (ignored without a body; clamped to the last frame).
    pub body_frames: Vec<Vec<[f32; 3]>>,
    /// Targets per frame, one per garment vertex, m (clamped to the last): where the body
    /// carries each vertex, which the pinned ones follow and the off-body metric measures drift
    /// and shift from ([`Animation::skins_garment`]). Empty: the initial positions, held (no
    /// shift is measured).
    pub pin_targets: Vec<Vec<[f32; 3]>>,
    /// Garment positions at frame 0, m.
    pub initial: Vec<[f32; 3]>,
    /// Garment velocities at frame 0, m per frame (empty: at rest).
    pub initial_velocity: Vec<[f32; 3]>,
    /// Number of frames.
    pub frames: usize,
}

impl Playback {
    /// The first `frames` frames of `anim` (clamped to its length), copied.
    ///
    /// # Errors
    /// Errors of `anim`.
    pub fn record(anim: &dyn Animation, frames: usize) -> Result<Playback> {
        let frames = frames.min(anim.n_frames()).max(1);
        let n = anim.garment().n_vertices();
        let mut pin_targets = Vec::with_capacity(frames);
        for f in 0..frames {
            let mut t = vec![[0.0; 3]; n];
            anim.pin_targets(f, &mut t)?;
            pin_targets.push(t);
        }
        let body_frames = match anim.body_mesh() {
            Some(_) => (0..frames).map(|f| anim.body_frame(f).to_vec()).collect(),
            None => Vec::new(),
        };
        Ok(Playback {
            garment: anim.garment().clone(),
            body: anim.body_mesh().cloned(),
            body_frames,
            pin_targets,
            initial: anim.initial_garment()?,
            initial_velocity: anim.initial_velocity()?,
            frames,
        })
    }

    /// A garment without a body starting at its rest shape, pinned vertices held in place,
    /// for `frames` frames.
    pub fn cloth_only(garment: Garment, frames: usize) -> Playback {
        let initial = garment.rest().to_vec();
        Playback {
            garment,
            body: None,
            body_frames: Vec::new(),
            pin_targets: Vec::new(),
            initial,
            initial_velocity: Vec::new(),
            frames,
        }
    }
}

impl Animation for Playback {
    fn garment(&self) -> &Garment {
        &self.garment
    }
    fn body_mesh(&self) -> Option<&BodyMesh> {
        self.body.as_ref()
    }
    fn n_frames(&self) -> usize {
        self.frames
    }
    fn body_frame(&self, f: usize) -> &[[f32; 3]] {
        match (&self.body, self.body_frames.len()) {
            (Some(_), k) if k > 0 => &self.body_frames[f.min(k - 1)],
            _ => &[],
        }
    }
    fn pin_targets(&self, f: usize, out: &mut [[f32; 3]]) -> Result<()> {
        let src = match self.pin_targets.len() {
            0 => &self.initial,
            k => &self.pin_targets[f.min(k - 1)],
        };
        if out.len() != src.len() {
            return Err(Error::SizeMismatch { what: "pin targets", expected: src.len(), got: out.len() });
        }
        out.copy_from_slice(src);
        Ok(())
    }
    fn initial_garment(&self) -> Result<Vec<[f32; 3]>> {
        Ok(self.initial.clone())
    }
    fn skins_garment(&self) -> bool {
        !self.pin_targets.is_empty()
    }
    fn initial_velocity(&self) -> Result<Vec<[f32; 3]>> {
        match self.initial_velocity.len() {
            0 => Ok(vec![[0.0; 3]; self.garment.n_vertices()]),
            k if k == self.garment.n_vertices() => Ok(self.initial_velocity.clone()),
            k => Err(Error::SizeMismatch { what: "initial velocity", expected: self.garment.n_vertices(), got: k }),
        }
    }
}
