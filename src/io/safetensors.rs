//! Safetensors files (through the `safetensors` crate): the reference implementation's
//! checkpoints, the parity fixtures and the trainer's checkpoints. [`SafeTensors`] holds a file
//! validated once and converts its tensors to the element types `hood` computes in.

use crate::error::{Error, Result};
use std::format;
use std::path::Path;
use std::string::{String, ToString};
use std::vec::Vec;

/// Element types `hood` reads (files with other types are refused when opened).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    /// IEEE single.
    F32,
    /// IEEE double.
    F64,
    /// IEEE half.
    F16,
    /// bfloat16.
    BF16,
    /// Signed 64-bit integer.
    I64,
    /// Signed 32-bit integer.
    I32,
    /// Unsigned byte.
    U8,
    /// Boolean (one byte).
    Bool,
}

impl Dtype {
    fn from_file(d: safetensors::Dtype) -> Option<Dtype> {
        use safetensors::Dtype as D;
        Some(match d {
            D::F32 => Dtype::F32,
            D::F64 => Dtype::F64,
            D::F16 => Dtype::F16,
            D::BF16 => Dtype::BF16,
            D::I64 => Dtype::I64,
            D::I32 => Dtype::I32,
            D::U8 => Dtype::U8,
            D::BOOL => Dtype::Bool,
            _ => return None,
        })
    }

    fn name(self) -> &'static str {
        match self {
            Dtype::F32 => "F32",
            Dtype::F64 => "F64",
            Dtype::F16 => "F16",
            Dtype::BF16 => "BF16",
            Dtype::I64 => "I64",
            Dtype::I32 => "I32",
            Dtype::U8 => "U8",
            Dtype::Bool => "BOOL",
        }
    }

    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Dtype::F64 | Dtype::I64 => 8,
            Dtype::F32 | Dtype::I32 => 4,
            Dtype::F16 | Dtype::BF16 => 2,
            Dtype::U8 | Dtype::Bool => 1,
        }
    }
}

/// Where one tensor lives in the file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TensorInfo {
    /// Element type.
    pub dtype: Dtype,
    /// Shape (row-major).
    pub shape: Vec<usize>,
    /// Byte range within the data section.
    pub range: (usize, usize),
}

impl TensorInfo {
    /// Number of elements.
    pub fn numel(&self) -> usize {
        self.shape.iter().product()
    }
}

/// A tensor converted to one element type.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor<T> {
    /// Shape (row-major).
    pub shape: Vec<usize>,
    /// Elements.
    pub data: Vec<T>,
}

impl<T: Copy> Tensor<T> {
    /// The data as rows of `N` (for `(n, N)` tensors such as positions or faces).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when the last dimension is not `N`.
    pub fn rows<const N: usize>(&self) -> Result<Vec<[T; N]>> {
        if self.shape.last() != Some(&N) && !(N == 1 && self.shape.is_empty()) {
            return Err(Error::SizeMismatch {
                what: "tensor row width",
                expected: N,
                got: self.shape.last().copied().unwrap_or(0),
            });
        }
        Ok(self.data.chunks_exact(N).map(|c| core::array::from_fn(|i| c[i])).collect())
    }
}

/// A safetensors file held in memory.
#[derive(Clone, Debug)]
pub struct SafeTensors {
    bytes: Vec<u8>,
    data_start: usize,
    tensors: Vec<(String, TensorInfo)>,
    metadata: Vec<(String, String)>,
}

impl SafeTensors {
    /// Reads and validates a file.
    ///
    /// # Errors
    /// [`Error::Io`] when the file cannot be read; see [`SafeTensors::from_bytes`].
    pub fn read(path: impl AsRef<Path>) -> Result<SafeTensors> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        SafeTensors::from_bytes(bytes)
    }

    /// Validates `bytes` (the header, and every tensor's byte range inside the data and
    /// matching its shape).
    ///
    /// # Errors
    /// [`Error::Parse`] (format `"safetensors"`) for a truncated or inconsistent file, or a
    /// tensor of an element type `hood` does not read.
    pub fn from_bytes(bytes: Vec<u8>) -> Result<SafeTensors> {
        let (header_len, meta) = safetensors::SafeTensors::read_metadata(&bytes)
            .map_err(|e| Error::parse("safetensors", 0, e.to_string()))?;
        let mut tensors = Vec::new();
        for name in meta.offset_keys() {
            let Some(info) = meta.info(&name) else { continue };
            let dtype = Dtype::from_file(info.dtype).ok_or_else(|| {
                Error::parse("safetensors", 0, format!("tensor '{name}': element type {} not read", info.dtype))
            })?;
            tensors.push((name, TensorInfo { dtype, shape: info.shape.clone(), range: info.data_offsets }));
        }
        let mut metadata: Vec<(String, String)> =
            meta.metadata().iter().flatten().map(|(k, v)| (k.clone(), v.clone())).collect();
        metadata.sort();
        Ok(SafeTensors { bytes, data_start: 8 + header_len, tensors, metadata })
    }

    /// Names and descriptions of all tensors, in the order of their data.
    pub fn tensors(&self) -> &[(String, TensorInfo)] {
        &self.tensors
    }

    /// The `__metadata__` entries, sorted by key.
    pub fn metadata(&self) -> &[(String, String)] {
        &self.metadata
    }

    /// The description of tensor `name`.
    ///
    /// # Errors
    /// [`Error::Parse`] naming the missing tensor.
    pub fn info(&self, name: &str) -> Result<&TensorInfo> {
        self.tensors
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, i)| i)
            .ok_or_else(|| Error::parse("safetensors", 0, format!("no tensor named '{name}'")))
    }

    /// The raw little-endian bytes of tensor `name`.
    ///
    /// # Errors
    /// As [`info`](Self::info).
    pub fn bytes(&self, name: &str) -> Result<(&TensorInfo, &[u8])> {
        let info = self.info(name)?;
        Ok((info, &self.bytes[self.data_start + info.range.0..self.data_start + info.range.1]))
    }

    /// Tensor `name` converted to `f32` (from F32, F64, F16, BF16, or integer types).
    ///
    /// # Errors
    /// As [`info`](Self::info).
    pub fn f32(&self, name: &str) -> Result<Tensor<f32>> {
        self.convert(name, |dtype, c| match dtype {
            Dtype::F32 => f32::from_le_bytes([c[0], c[1], c[2], c[3]]),
            Dtype::F64 => f64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f32,
            Dtype::F16 => half::f16::from_le_bytes([c[0], c[1]]).to_f32(),
            Dtype::BF16 => half::bf16::from_le_bytes([c[0], c[1]]).to_f32(),
            Dtype::I64 => i64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f32,
            Dtype::I32 => i32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f32,
            Dtype::U8 | Dtype::Bool => c[0] as f32,
        })
    }

    /// Tensor `name` converted to `f64`.
    ///
    /// # Errors
    /// As [`info`](Self::info).
    pub fn f64(&self, name: &str) -> Result<Tensor<f64>> {
        let t = self.f32(name)?;
        if self.info(name)?.dtype == Dtype::F64 {
            return self.convert(name, |_, c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])));
        }
        Ok(Tensor { shape: t.shape, data: t.data.iter().map(|&x| x as f64).collect() })
    }

    /// Tensor `name` converted to `i64` (integer and boolean types only).
    ///
    /// # Errors
    /// As [`info`](Self::info); [`Error::Parse`] for a floating-point tensor.
    pub fn i64(&self, name: &str) -> Result<Tensor<i64>> {
        let dtype = self.info(name)?.dtype;
        if matches!(dtype, Dtype::F32 | Dtype::F64 | Dtype::F16 | Dtype::BF16) {
            return Err(Error::parse("safetensors", 0, format!("tensor '{name}' is {}, not integer", dtype.name())));
        }
        self.convert(name, |dtype, c| match dtype {
            Dtype::I64 => i64::from_le_bytes(c.try_into().unwrap_or([0; 8])),
            Dtype::I32 => i32::from_le_bytes([c[0], c[1], c[2], c[3]]) as i64,
            _ => c[0] as i64,
        })
    }

    fn convert<T>(&self, name: &str, f: impl Fn(Dtype, &[u8]) -> T) -> Result<Tensor<T>> {
        let (info, raw) = self.bytes(name)?;
        let data = raw.chunks_exact(info.dtype.size()).map(|c| f(info.dtype, c)).collect();
        Ok(Tensor { shape: info.shape.clone(), data })
    }
}

/// One tensor to write.
#[derive(Clone, Copy, Debug)]
pub enum TensorData<'a> {
    /// `f32` elements.
    F32(&'a [f32]),
    /// `f64` elements.
    F64(&'a [f64]),
    /// `i64` elements.
    I64(&'a [i64]),
}

/// Serialises tensors (and string metadata) to safetensors bytes.
///
/// # Errors
/// [`Error::SizeMismatch`] when a shape does not match its data length.
pub fn to_bytes(tensors: &[(&str, &[usize], TensorData<'_>)], metadata: &[(&str, &str)]) -> Result<Vec<u8>> {
    let mut owned = Vec::with_capacity(tensors.len());
    for (name, shape, t) in tensors {
        let numel: usize = shape.iter().product();
        let (dtype, len, bytes): (_, _, Vec<u8>) = match t {
            TensorData::F32(v) => (safetensors::Dtype::F32, v.len(), v.iter().flat_map(|x| x.to_le_bytes()).collect()),
            TensorData::F64(v) => (safetensors::Dtype::F64, v.len(), v.iter().flat_map(|x| x.to_le_bytes()).collect()),
            TensorData::I64(v) => (safetensors::Dtype::I64, v.len(), v.iter().flat_map(|x| x.to_le_bytes()).collect()),
        };
        if len != numel {
            return Err(Error::SizeMismatch { what: "tensor data for its shape", expected: numel, got: len });
        }
        owned.push((*name, dtype, shape.to_vec(), bytes));
    }
    let mut views = Vec::with_capacity(owned.len());
    for (name, dtype, shape, bytes) in &owned {
        let view = safetensors::tensor::TensorView::new(*dtype, shape.clone(), bytes)
            .map_err(|e| Error::parse("safetensors", 0, format!("tensor '{name}': {e}")))?;
        views.push((*name, view));
    }
    let info = (!metadata.is_empty()).then(|| metadata.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect());
    safetensors::serialize(views.iter().map(|(n, v)| (*n, v)), info)
        .map_err(|e| Error::parse("safetensors", 0, format!("writing: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn safetensors_round_trip_and_truncation() {
        let a = [1.5f32, -2.0, 3.25, 4.0, 5.0, 6.0];
        let b = [7i64, -8];
        let bytes =
            to_bytes(&[("a", &[2, 3], TensorData::F32(&a)), ("b\"q", &[2], TensorData::I64(&b))], &[("k", "v")])
                .unwrap();
        let st = SafeTensors::from_bytes(bytes.clone()).unwrap();
        let t = st.f32("a").unwrap();
        assert_eq!(t.shape, std::vec![2, 3]);
        assert_eq!(t.data, a);
        assert_eq!(t.rows::<3>().unwrap()[1], [4.0, 5.0, 6.0]);
        assert!(t.rows::<2>().is_err());
        assert_eq!(st.i64("b\"q").unwrap().data, b);
        assert!(st.i64("a").is_err());
        assert!(st.f32("missing").is_err());
        assert_eq!(st.metadata(), &[("k".to_string(), "v".to_string())]);
        for cut in 0..bytes.len() {
            assert!(SafeTensors::from_bytes(bytes[..cut].to_vec()).is_err(), "truncated at {cut} accepted");
        }
    }

    #[test]
    fn safetensors_reads_what_the_crate_writes_and_refuses_unread_types() {
        use safetensors::tensor::TensorView;
        let h: Vec<u8> = [1.5f32, -0.25].iter().flat_map(|&x| half::f16::from_f32(x).to_le_bytes()).collect();
        let flags = [1u8, 0, 1];
        let views = [
            ("half", TensorView::new(safetensors::Dtype::F16, std::vec![2], &h).unwrap()),
            ("flags", TensorView::new(safetensors::Dtype::BOOL, std::vec![3], &flags).unwrap()),
        ];
        let bytes = safetensors::serialize(views.iter().map(|(n, v)| (*n, v)), None).unwrap();
        let st = SafeTensors::from_bytes(bytes).unwrap();
        assert_eq!(st.f32("half").unwrap().data, [1.5, -0.25]);
        assert_eq!(st.i64("flags").unwrap().data, [1, 0, 1]);
        assert_eq!(st.info("flags").unwrap().dtype, Dtype::Bool);
        assert!(st.metadata().is_empty());

        let wide = [0u8; 4];
        let view = TensorView::new(safetensors::Dtype::U16, std::vec![2], &wide).unwrap();
        let bytes = safetensors::serialize([("u16", &view)], None).unwrap();
        let e = SafeTensors::from_bytes(bytes).unwrap_err();
        assert!(std::format!("{e}").contains("u16"), "{e}");
    }

    #[test]
    fn safetensors_reads_the_fixture_header() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/fixtures/hood-parity/fixture_scene.safetensors");
        if !std::path::Path::new(path).exists() {
            std::println!("skipped: {path} not present");
            return;
        }
        let st = SafeTensors::read(path).unwrap();
        let faces = st.i64("cloth_faces").unwrap();
        assert_eq!(faces.shape, std::vec![2524, 3]);
        assert_eq!(st.f32("cloth_pos").unwrap().shape, std::vec![1311, 3]);
    }
}
