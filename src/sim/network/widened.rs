//! A model's bf16 weights widened to f32 once, for CPUs without bf16 products.
//!
//! There the kernels would widen bf16 weights on every call (and round the activations to bf16
//! to compute the same products as `vdpbf16ps`), which makes bf16 slower than f32. Widened once,
//! when a [`Sim`](crate::sim::Sim) is made, the bf16 weights run on the f32 kernels at the f32 cost:
//! bf16-exact weights, f32 activations and arithmetic. The copy is owned by the simulation and
//! costs the f32 size of the weights past the encoders (which run in f32 at every precision); a
//! simulation that does not need it has none.

use super::LayerParts;
use crate::error::{Error, Result};
use crate::kernels::{packed_len_f32, PackedF32, Weights, MAX_OPERANDS};
use crate::model::file::Model;
use alloc::vec;
use alloc::vec::Vec;
use core::ops::Range;

/// Where one widened part lives in [`WidenedBf16`]'s buffer.
#[derive(Clone, Copy, Debug)]
struct Part {
    start: usize,
    k: usize,
    n: usize,
}

/// Every bf16 weight part of a model, widened to the f32 panel layout, found by
/// [`LinearView::index`](crate::model::file::LinearView::index).
#[derive(Clone, Debug)]
pub struct WidenedBf16 {
    data: Vec<f32>,
    parts: Vec<Part>,
    /// `parts` of each layer, by layer index.
    layers: Vec<Range<usize>>,
}

impl WidenedBf16 {
    /// Widens every bf16 part of `model` past its encoders (allocates the f32 size of those
    /// weights).
    ///
    /// # Errors
    /// [`Error::UnsupportedEffect`] for a model file without bf16 weights;
    /// [`Error::IncompatibleModel`] for a layer of more parts than a kernel call sums.
    pub fn new(model: &Model<'_>) -> Result<WidenedBf16> {
        if !model.has_bf16() {
            return Err(Error::UnsupportedEffect { effect: "bf16 precision (the model file has no bf16 weights)" });
        }
        let layers_of = || model.mlps.iter().flat_map(|m| &m.layers);
        // The encoders, the first layers, run in f32 at every precision (`Net::encoders`).
        let encoder_layers: usize = model.mlps.encoders().map(|m| m.layers.len()).sum();
        let widened = || layers_of().skip(encoder_layers);
        let len: usize = widened().flat_map(|l| &l.bf16).map(|w| packed_len_f32(w.k(), w.n())).sum();
        let mut w = WidenedBf16 { data: vec![0.0; len], parts: Vec::new(), layers: Vec::new() };
        let mut start = 0;
        for (index, layer) in layers_of().enumerate() {
            if layer.index != index {
                return Err(Error::IncompatibleModel { reason: "model layers out of order" });
            }
            if index < encoder_layers {
                w.layers.push(0..0);
                continue;
            }
            if layer.bf16.len() > MAX_OPERANDS {
                return Err(Error::IncompatibleModel { reason: "a layer has more parts than a kernel call sums" });
            }
            let first = w.parts.len();
            for part in &layer.bf16 {
                let Weights::Bf16(b) = part else {
                    return Err(Error::IncompatibleModel { reason: "a bf16 weight part is not bf16" });
                };
                let end = start + packed_len_f32(b.k(), b.n());
                b.widen_into(&mut w.data[start..end])?;
                w.parts.push(Part { start, k: b.k(), n: b.n() });
                start = end;
            }
            w.layers.push(first..w.parts.len());
        }
        Ok(w)
    }

    /// The widened parts of layer `index` ([`LinearView::index`]).
    ///
    /// [`LinearView::index`]: crate::model::file::LinearView::index
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for a layer this model does not have.
    pub fn parts(&self, index: usize) -> Result<LayerParts<'_>> {
        let range = self.layers.get(index).ok_or(Error::OutOfRange { what: "widened layer", index })?;
        LayerParts::collect(self.parts[range.clone()].iter().map(|p| {
            let data = &self.data[p.start..p.start + packed_len_f32(p.k, p.n)];
            PackedF32::new(data, p.k, p.n).map(Weights::F32)
        }))
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.data.len() * core::mem::size_of::<f32>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::file::{write_model, ModelBytes};
    use crate::model::params::Params;
    use crate::model::spec::ModelSpec;

    #[test]
    fn runtime_widened_bf16_parts_hold_the_bf16_weights_exactly() {
        let spec = ModelSpec::hood(16);
        let params = Params::init(&spec, 3).unwrap();
        let bytes = ModelBytes::new(&write_model(&params, true, &[]).unwrap());
        let model = bytes.model().unwrap();
        let wide = WidenedBf16::new(&model).unwrap();
        let mut n_layers = 0;
        let encoder_layers: usize = model.mlps.encoders().map(|m| m.layers.len()).sum();
        assert!(encoder_layers >= 3 * 3, "node, mesh and body encoders at least");
        let mut widened_len = 0;
        for layer in model.mlps.iter().flat_map(|m| &m.layers) {
            n_layers += 1;
            if layer.index < encoder_layers {
                assert!(wide.parts(layer.index).is_err(), "the encoders run in f32: nothing widened");
                continue;
            }
            widened_len += layer.bf16.iter().map(|b| packed_len_f32(b.k(), b.n())).sum::<usize>();
            let parts = wide.parts(layer.index).unwrap();
            assert_eq!(parts.len(), layer.bf16.len());
            for (w, b) in parts.iter().zip(&layer.bf16) {
                let (Weights::F32(w), Weights::Bf16(b)) = (w, b) else { panic!("f32 widened from bf16") };
                assert_eq!((w.k(), w.n()), (b.k(), b.n()));
                for o in 0..b.n() {
                    for kk in 0..b.k() {
                        assert_eq!(w.get(kk, o).to_bits(), b.get(kk, o).to_bits());
                    }
                }
            }
        }
        assert!(wide.parts(n_layers).is_err());
        assert_eq!(wide.bytes(), widened_len * 4);
        // A file without bf16 weights has nothing to widen.
        let f32_only = ModelBytes::new(&write_model(&params, false, &[]).unwrap());
        assert!(WidenedBf16::new(&f32_only.model().unwrap()).is_err());
    }
}
