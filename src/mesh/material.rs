//! Cloth materials (MODEL.md section 3): SI parameters and their network encoding.

use crate::error::{Error, Result};
use crate::math::Real;
use alloc::format;
use alloc::vec::Vec;

/// Material parameters of a cloth vertex, in SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Area density, kg/m^2. Training range [0.0434, 0.7].
    pub density: f32,
    /// Lamé mu (shear stiffness), Pa. Training range [15909, 63636], log-uniform.
    pub mu: f32,
    /// Lamé lambda, Pa. Training range [3535.41, 93333.74], uniform.
    pub lambda: f32,
    /// Bending stiffness k_bend, J (N·m). Training range [6.3708e-8, 1.31397e-3], log-uniform.
    pub bending: f32,
}

/// The documented training ranges (inclusive) of each material parameter.
pub mod ranges {
    /// Density range, kg/m^2.
    pub const DENSITY: (f32, f32) = (0.0434, 0.7);
    /// Lamé mu range, Pa.
    pub const MU: (f32, f32) = (15909.0, 63636.0);
    /// Lamé lambda range, Pa.
    pub const LAMBDA: (f32, f32) = (3535.41, 93333.74);
    /// Bending stiffness range.
    pub const BENDING: (f32, f32) = (6.3708e-8, 1.31397e-3);
}

impl Default for Material {
    /// The reference implementation's inference material.
    fn default() -> Self {
        Material { density: 0.20022, mu: 23600.0, lambda: 44400.0, bending: 3.962_577_8e-5_f64 as f32 }
    }
}

impl core::fmt::Display for Material {
    /// `density,mu,lambda,bending`, each the shortest text that reads back to the same `f32`:
    /// what [`Material::parse`] reads.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{},{},{},{}", self.density, self.mu, self.lambda, self.bending)
    }
}

impl Material {
    /// Names of [`Material::preset`]: the default and, for stretching (Lamé mu and lambda
    /// together) and bending separately, each end of the training ranges.
    pub const PRESETS: [&'static str; 5] = ["default", "soft-stretch", "stiff-stretch", "soft-bend", "stiff-bend"];

    /// A named material: `default` ([`Material::default`]), `soft-stretch` / `stiff-stretch`
    /// (mu and lambda at the low / high end of their training ranges, the rest default),
    /// `soft-bend` / `stiff-bend` (bending stiffness at either end). `None` for other names.
    pub fn preset(name: &str) -> Option<Material> {
        let d = Material::default();
        Some(match name {
            "default" => d,
            "soft-stretch" => Material { mu: ranges::MU.0, lambda: ranges::LAMBDA.0, ..d },
            "stiff-stretch" => Material { mu: ranges::MU.1, lambda: ranges::LAMBDA.1, ..d },
            "soft-bend" => Material { bending: ranges::BENDING.0, ..d },
            "stiff-bend" => Material { bending: ranges::BENDING.1, ..d },
            _ => return None,
        })
    }

    /// A material as text: a name of [`Material::PRESETS`], or four numbers
    /// `density,mu,lambda,bending` in the fields' SI units (kg/m^2, Pa, Pa, J).
    ///
    /// # Errors
    /// [`Error::Parse`] (format `"material"`) for another name, a number that does not parse
    /// or a material that is not [`valid`](Self::is_valid).
    pub fn parse(text: &str) -> Result<Material> {
        if let Some(m) = Material::preset(text) {
            return Ok(m);
        }
        let numbers: Vec<f32> =
            text.split(',').map(|t| t.trim().parse::<f32>()).collect::<core::result::Result<_, _>>().map_err(|_| {
                Error::parse(
                    "material",
                    0,
                    format!("'{text}': not a preset ({}) nor density,mu,lambda,bending", Material::PRESETS.join(", ")),
                )
            })?;
        let [density, mu, lambda, bending] = numbers[..] else {
            return Err(Error::parse(
                "material",
                0,
                format!("'{text}': four numbers density,mu,lambda,bending, not {}", numbers.len()),
            ));
        };
        let m = Material { density, mu, lambda, bending };
        if !m.is_valid() {
            return Err(Error::parse("material", 0, format!("'{text}': every parameter must be finite and positive")));
        }
        Ok(m)
    }

    /// True when every parameter is finite and strictly positive.
    pub fn is_valid(&self) -> bool {
        [self.density, self.mu, self.lambda, self.bending].iter().all(|v| v.is_finite() && *v > 0.0)
    }

    /// The network's material inputs `(bend_in, mu_in, lambda_in)`, each in [0, 1] over the
    /// training ranges (log-relative for bending and mu, linear for lambda). This order is the
    /// order of node feature columns 21-23 and edge feature columns 9-11.
    pub fn network_inputs(&self) -> [f32; 3] {
        fn log_rel(v: f32, (lo, hi): (f32, f32)) -> f32 {
            let (v, lo, hi) = (v as f64, lo as f64, hi as f64);
            ((v.ln() - lo.ln()) / (hi.ln() - lo.ln())) as f32
        }
        let lin = |v: f32, (lo, hi): (f32, f32)| ((v as f64 - lo as f64) / (hi as f64 - lo as f64)) as f32;
        [log_rel(self.bending, ranges::BENDING), log_rel(self.mu, ranges::MU), lin(self.lambda, ranges::LAMBDA)]
    }

    /// Mean of several materials (parameter-wise arithmetic mean), used where a face or hinge
    /// spans vertices of different materials.
    pub fn mean<T: Real>(ms: &[Material]) -> [T; 4] {
        let mut acc = [T::ZERO; 4];
        for m in ms {
            acc[0] += T::from_f32(m.density);
            acc[1] += T::from_f32(m.mu);
            acc[2] += T::from_f32(m.lambda);
            acc[3] += T::from_f32(m.bending);
        }
        let n = T::from_f64(ms.len().max(1) as f64);
        acc.map(|a| a / n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::string::ToString;

    #[test]
    fn garment_material_inputs_match_reference() {
        // Fixture README: network inputs (bending, mu, lambda) = [0.6475499, 0.2844717, 0.4550707].
        let got = Material::default().network_inputs();
        let want = [0.6475499f32, 0.2844717, 0.4550707];
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 2e-6, "{got:?} vs {want:?}");
        }
    }

    #[test]
    fn material_parses_presets_and_numbers_and_refuses_the_rest() {
        assert_eq!(Material::parse("stiff-bend").unwrap(), Material::preset("stiff-bend").unwrap());
        let m = Material::parse("0.3, 20000,40000,1e-5").unwrap();
        assert_eq!(m, Material { density: 0.3, mu: 20000.0, lambda: 40000.0, bending: 1e-5 });
        // The text form reads back to the same material, bit for bit.
        for m in [m, Material::preset("stiff-bend").unwrap(), Material::default()] {
            assert_eq!(Material::parse(&m.to_string()).unwrap(), m);
        }
        for bad in ["silk", "0.3,20000,40000", "0.3,20000,40000,1e-5,1", "0.3,-1,40000,1e-5", "0.3,nan,1,1", ""] {
            assert!(matches!(Material::parse(bad), Err(Error::Parse { format: "material", .. })), "{bad}");
        }
    }
}
