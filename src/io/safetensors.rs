//! Reader and writer for the safetensors format (8-byte little-endian header length, a JSON
//! header naming each tensor's dtype, shape and byte range, then the raw little-endian data).
//! Used for the reference implementation's checkpoints and for the parity fixtures.

use crate::error::{Error, Result};
use crate::io::json::Json;
use std::format;
use std::path::Path;
use std::string::{String, ToString};
use std::vec::Vec;

/// Element types `hood` reads.
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
    fn parse(s: &str) -> Option<Dtype> {
        Some(match s {
            "F32" => Dtype::F32,
            "F64" => Dtype::F64,
            "F16" => Dtype::F16,
            "BF16" => Dtype::BF16,
            "I64" => Dtype::I64,
            "I32" => Dtype::I32,
            "U8" => Dtype::U8,
            "BOOL" => Dtype::Bool,
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

fn corrupt(reason: &'static str) -> Error {
    Error::CorruptData { reason }
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

    /// Validates the header of `bytes` (every range inside the data and matching its shape).
    ///
    /// # Errors
    /// [`Error::CorruptData`] for a truncated or inconsistent file, [`Error::Parse`] for a bad header.
    pub fn from_bytes(bytes: Vec<u8>) -> Result<SafeTensors> {
        let len_bytes: [u8; 8] = bytes
            .get(..8)
            .ok_or(corrupt("safetensors: shorter than its header length"))?
            .try_into()
            .map_err(|_| corrupt("safetensors: header length"))?;
        let header_len = u64::from_le_bytes(len_bytes);
        let data_start = 8usize
            .checked_add(usize::try_from(header_len).map_err(|_| corrupt("safetensors: header too long"))?)
            .filter(|&e| e <= bytes.len())
            .ok_or(corrupt("safetensors: header runs past the end of the file"))?;
        let text = core::str::from_utf8(&bytes[8..data_start]).map_err(|_| corrupt("safetensors: header not UTF-8"))?;
        let header = Json::parse(text)?;
        let members = header.as_object().ok_or(corrupt("safetensors: header is not an object"))?;
        let data_len = bytes.len() - data_start;
        let mut tensors = Vec::new();
        let mut metadata = Vec::new();
        for (name, v) in members {
            if name == "__metadata__" {
                for (k, m) in v.as_object().unwrap_or(&[]) {
                    metadata.push((k.clone(), m.as_str().unwrap_or_default().to_string()));
                }
                continue;
            }
            let bad = |m: &str| Error::parse("safetensors", 0, format!("tensor '{name}': {m}"));
            let dtype = v.get("dtype").and_then(Json::as_str).and_then(Dtype::parse).ok_or_else(|| bad("dtype"))?;
            let shape: Vec<usize> = v
                .get("shape")
                .and_then(Json::as_f64_vec)
                .ok_or_else(|| bad("shape"))?
                .iter()
                .map(|&d| d as usize)
                .collect();
            let off = v.get("data_offsets").and_then(Json::as_f64_vec).ok_or_else(|| bad("data_offsets"))?;
            let (a, b) = match off[..] {
                [a, b] if a >= 0.0 && b >= a => (a as usize, b as usize),
                _ => return Err(bad("data_offsets")),
            };
            let numel = shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d)).ok_or_else(|| bad("shape"))?;
            if b > data_len || numel.checked_mul(dtype.size()) != Some(b - a) {
                return Err(corrupt("safetensors: a tensor's byte range disagrees with its shape or the file size"));
            }
            tensors.push((name.clone(), TensorInfo { dtype, shape, range: (a, b) }));
        }
        Ok(SafeTensors { bytes, data_start, tensors, metadata })
    }

    /// Names and descriptions of all tensors, in header order.
    pub fn tensors(&self) -> &[(String, TensorInfo)] {
        &self.tensors
    }

    /// The `__metadata__` entries.
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
    pub fn bytes(&self, name: &str) -> Result<(&TensorInfo, &[u8])> {
        let info = self.info(name)?;
        Ok((info, &self.bytes[self.data_start + info.range.0..self.data_start + info.range.1]))
    }

    /// Tensor `name` converted to `f32` (from F32, F64, F16, BF16, or integer types).
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
    pub fn f64(&self, name: &str) -> Result<Tensor<f64>> {
        let t = self.f32(name)?;
        if self.info(name)?.dtype == Dtype::F64 {
            return self.convert(name, |_, c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])));
        }
        Ok(Tensor { shape: t.shape, data: t.data.iter().map(|&x| x as f64).collect() })
    }

    /// Tensor `name` converted to `i64` (integer and boolean types only).
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
    fn esc(s: &str) -> String {
        s.chars()
            .flat_map(|c| match c {
                '"' => "\\\"".chars().collect::<Vec<_>>(),
                '\\' => "\\\\".chars().collect(),
                c if (c as u32) < 0x20 => format!("\\u{:04x}", c as u32).chars().collect(),
                c => std::vec![c],
            })
            .collect()
    }
    let mut header = String::from("{");
    if !metadata.is_empty() {
        header.push_str("\"__metadata__\":{");
        let items: Vec<String> = metadata.iter().map(|(k, v)| format!("\"{}\":\"{}\"", esc(k), esc(v))).collect();
        header.push_str(&items.join(","));
        header.push_str("},");
    }
    let mut data = Vec::new();
    let mut items = Vec::new();
    for (name, shape, t) in tensors {
        let numel: usize = shape.iter().product();
        let (dtype, len, start) = match t {
            TensorData::F32(v) => {
                let s = data.len();
                v.iter().for_each(|x| data.extend_from_slice(&x.to_le_bytes()));
                ("F32", v.len(), s)
            }
            TensorData::F64(v) => {
                let s = data.len();
                v.iter().for_each(|x| data.extend_from_slice(&x.to_le_bytes()));
                ("F64", v.len(), s)
            }
            TensorData::I64(v) => {
                let s = data.len();
                v.iter().for_each(|x| data.extend_from_slice(&x.to_le_bytes()));
                ("I64", v.len(), s)
            }
        };
        if len != numel {
            return Err(Error::SizeMismatch { what: "tensor data for its shape", expected: numel, got: len });
        }
        let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
        items.push(format!(
            "\"{}\":{{\"dtype\":\"{dtype}\",\"shape\":[{}],\"data_offsets\":[{start},{}]}}",
            esc(name),
            dims.join(","),
            data.len()
        ));
    }
    header.push_str(&items.join(","));
    header.push('}');
    while (8 + header.len()) % 8 != 0 {
        header.push(' ');
    }
    let mut out = Vec::with_capacity(8 + header.len() + data.len());
    out.extend_from_slice(&(header.len() as u64).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(&data);
    Ok(out)
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
