//! Feature normalisers (MODEL.md section 3): running sums during training, frozen statistics at
//! inference.

use alloc::vec;
use alloc::vec::Vec;

/// Smallest standard deviation used, so that a constant column does not divide by zero.
pub const STD_EPSILON: f32 = 1e-8;

/// Running statistics of `width` columns: sums, sums of squares and the row count.
#[derive(Clone, Debug, PartialEq)]
pub struct Normaliser {
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
    count: f64,
}

impl Normaliser {
    /// Empty statistics for `width` columns.
    pub fn new(width: usize) -> Self {
        Normaliser { sum: vec![0.0; width], sum_sq: vec![0.0; width], count: 0.0 }
    }

    /// From stored accumulators (e.g. a reference checkpoint's `_acc_sum`, `_acc_sum_squared`,
    /// `_acc_count`).
    pub fn from_accumulators(sum: &[f64], sum_sq: &[f64], count: f64) -> Self {
        Normaliser { sum: sum.to_vec(), sum_sq: sum_sq.to_vec(), count }
    }

    /// Number of columns.
    pub fn width(&self) -> usize {
        self.sum.len()
    }

    /// Rows accumulated so far.
    pub fn count(&self) -> f64 {
        self.count
    }

    /// The accumulators `(sum, sum of squares, count)`.
    pub fn accumulators(&self) -> (&[f64], &[f64], f64) {
        (&self.sum, &self.sum_sq, self.count)
    }

    /// Adds the first `width` columns of each row of `rows` (row length `stride`).
    pub fn accumulate(&mut self, rows: &[f32], stride: usize) {
        let w = self.width();
        for row in rows.chunks_exact(stride) {
            for c in 0..w {
                let x = row[c] as f64;
                self.sum[c] += x;
                self.sum_sq[c] += x * x;
            }
            self.count += 1.0;
        }
    }

    /// Frozen statistics: `mean = sum / max(count, 1)`,
    /// `std = max(sqrt(max(sum_sq / count - mean^2, 0)), 1e-8)`.
    pub fn stats(&self) -> NormStats {
        let n = self.count.max(1.0);
        let mean: Vec<f32> = self.sum.iter().map(|s| (s / n) as f32).collect();
        let std = self
            .sum_sq
            .iter()
            .zip(&self.sum)
            .map(|(sq, s)| {
                let m = s / n;
                (crate::math::sqrt_f64((sq / n - m * m).max(0.0)) as f32).max(STD_EPSILON)
            })
            .collect();
        NormStats { mean, std }
    }
}

/// Frozen mean and standard deviation per column.
#[derive(Clone, Debug, PartialEq)]
pub struct NormStats {
    /// Column means.
    pub mean: Vec<f32>,
    /// Column standard deviations (at least [`STD_EPSILON`]).
    pub std: Vec<f32>,
}

/// Normalises the first `mean.len()` columns of every row in place: `x <- (x - mean) / std`.
/// Rows have length `stride`; further columns are left as they are.
pub fn normalise_rows(rows: &mut [f32], stride: usize, mean: &[f32], std: &[f32]) {
    let w = mean.len().min(std.len()).min(stride);
    for row in rows.chunks_exact_mut(stride) {
        for c in 0..w {
            row[c] = (row[c] - mean[c]) / std[c];
        }
    }
}

/// The inverse: `x <- x * std + mean` on the first `mean.len()` columns.
pub fn denormalise_rows(rows: &mut [f32], stride: usize, mean: &[f32], std: &[f32]) {
    let w = mean.len().min(std.len()).min(stride);
    for row in rows.chunks_exact_mut(stride) {
        for c in 0..w {
            row[c] = row[c] * std[c] + mean[c];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn features_normaliser_statistics() {
        let mut n = Normaliser::new(2);
        n.accumulate(&[1.0, 5.0, 9.0, 3.0, 5.0, 9.0, 2.0, 5.0, 9.0], 3);
        let s = n.stats();
        assert_eq!(s.mean, vec![2.0, 5.0]);
        assert!((s.std[0] - (2.0f32 / 3.0).sqrt()).abs() < 1e-6);
        assert_eq!(s.std[1], STD_EPSILON);
        let mut rows = vec![3.0, 5.0, 7.0];
        normalise_rows(&mut rows, 3, &s.mean, &s.std);
        assert!((rows[0] - 1.0 / (2.0f32 / 3.0).sqrt()).abs() < 1e-5 && rows[1] == 0.0 && rows[2] == 7.0);
        denormalise_rows(&mut rows, 3, &s.mean, &s.std);
        assert!((rows[0] - 3.0).abs() < 1e-6 && rows[1] == 5.0);
    }
}
