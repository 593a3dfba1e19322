//! Reading a safetensors file: [`TensorFile`] parses the header and hands out tensors after
//! checking their dtype, shape and values, naming the file and tensor in every error.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Metadata, TensorInfo};
use safetensors::{Dtype, SafeTensorError};

use crate::Tensor;
use crate::error::{Error, Result};

/// A parsed safetensors file held in memory.
#[derive(Debug)]
pub struct TensorFile {
    what: String,
    bytes: Vec<u8>,
    data_start: usize,
    tensors: HashMap<String, TensorInfo>,
    metadata: HashMap<String, String>,
}

fn describe(e: SafeTensorError) -> String {
    match e {
        SafeTensorError::MetadataIncompleteBuffer | SafeTensorError::InvalidOffset(_) => {
            format!("the file is truncated or its header does not match its size ({e})")
        }
        SafeTensorError::HeaderTooSmall | SafeTensorError::HeaderTooLarge => {
            format!("the header is missing or corrupt ({e})")
        }
        other => other.to_string(),
    }
}

impl TensorFile {
    pub fn open(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::from_bytes(bytes, path.display().to_string())
    }

    /// Parses a file already in memory (e.g. fetched in the browser); `what` names it in errors.
    pub fn from_bytes(bytes: Vec<u8>, what: impl Into<String>) -> Result<Self> {
        let what = what.into();
        let format_err = |detail: String| Error::Format {
            what: what.clone(),
            detail,
        };
        let (header_len, metadata): (usize, Metadata) =
            safetensors::SafeTensors::read_metadata(&bytes).map_err(|e| format_err(describe(e)))?;
        let data_start = 8 + header_len;
        let tensors: HashMap<String, TensorInfo> = metadata
            .tensors()
            .into_iter()
            .map(|(name, info)| (name, info.clone()))
            .collect();
        let meta = metadata.metadata().clone().unwrap_or_default();
        Ok(Self {
            what,
            bytes,
            data_start,
            tensors,
            metadata: meta,
        })
    }

    pub fn what(&self) -> &str {
        &self.what
    }
    pub fn metadata(&self, key: &str) -> Option<&str> {
        self.metadata.get(key).map(String::as_str)
    }
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.tensors.keys().map(String::as_str)
    }
    pub fn contains(&self, name: &str) -> bool {
        self.tensors.contains_key(name)
    }
    pub fn shape(&self, name: &str) -> Option<&[usize]> {
        self.tensors.get(name).map(|i| i.shape.as_slice())
    }

    fn info(&self, name: &str) -> Result<&TensorInfo> {
        self.tensors.get(name).ok_or_else(|| Error::MissingTensor {
            what: self.what.clone(),
            name: name.into(),
        })
    }

    /// A tensor's shape and raw bytes, after checking its dtype is one of `dtypes` and its
    /// shape is `shape` (`None` = any).
    fn checked(
        &self,
        name: &str,
        dtypes: &[Dtype],
        expected: &'static str,
        shape: Option<&[usize]>,
    ) -> Result<(&TensorInfo, &[u8])> {
        let info = self.info(name)?;
        if !dtypes.contains(&info.dtype) {
            return Err(Error::Dtype {
                what: self.what.clone(),
                name: name.into(),
                found: format!("{:?}", info.dtype),
                expected,
            });
        }
        if let Some(shape) = shape
            && info.shape != shape
        {
            return Err(Error::Shape {
                what: self.what.clone(),
                name: name.into(),
                found: info.shape.clone(),
                expected: format!("{shape:?}"),
            });
        }
        let (a, b) = info.data_offsets;
        Ok((info, &self.bytes[self.data_start + a..self.data_start + b]))
    }

    /// An f32 tensor (F16 is widened), checked for shape (`None` = any) and finiteness.
    pub fn f32(&self, name: &str, shape: Option<&[usize]>) -> Result<Tensor<f32>> {
        let (info, raw) = self.checked(name, &[Dtype::F32, Dtype::F16], "F32", shape)?;
        let data: Vec<f32> = if info.dtype == Dtype::F16 {
            raw.chunks_exact(2)
                .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
                .collect()
        } else {
            raw.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        let tensor = Tensor::from_vec(&info.shape, data).map_err(|_| Error::Format {
            what: self.what.clone(),
            detail: format!(
                "tensor `{name}` has {} bytes for shape {:?}",
                raw.len(),
                info.shape
            ),
        })?;
        if let Some((flat, value)) = tensor.first_non_finite() {
            return Err(Error::NonFinite {
                what: self.what.clone(),
                name: name.into(),
                index: tensor.unravel(flat),
                value: value as f64,
            });
        }
        Ok(tensor)
    }

    /// A U8 tensor (8-bit images), checked for shape (`None` = any); returns shape and bytes.
    pub fn u8(&self, name: &str, shape: Option<&[usize]>) -> Result<(Vec<usize>, Vec<u8>)> {
        let (info, raw) = self.checked(name, &[Dtype::U8], "U8", shape)?;
        Ok((info.shape.clone(), raw.to_vec()))
    }

    /// An integer tensor (I64 or I32) as `usize`s.
    pub fn indices(&self, name: &str) -> Result<Vec<usize>> {
        let (info, raw) = self.checked(name, &[Dtype::I64, Dtype::I32], "I64 or I32", None)?;
        // I64 or I32, as checked.
        let values: Vec<i64> = if info.dtype == Dtype::I64 {
            raw.chunks_exact(8)
                .map(|c| i64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
                .collect()
        } else {
            raw.chunks_exact(4)
                .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]) as i64)
                .collect()
        };
        values
            .into_iter()
            .map(|v| {
                usize::try_from(v).map_err(|_| Error::Format {
                    what: self.what.clone(),
                    detail: format!("`{name}` holds the negative value {v}"),
                })
            })
            .collect()
    }
}
