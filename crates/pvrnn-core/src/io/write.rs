//! Writing safetensors: the tensors to write ([`OutTensor`]) and their bytes with a
//! canonical header ([`to_bytes`]), so the same tensors and metadata always give the same
//! bytes; `save` writes them to a file atomically.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use safetensors::{Dtype, View};

use super::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::{Real, Tensor};

/// A tensor to write: f32 values (or f16, half the size), i64 indices or u8 bytes (images).
#[derive(Debug)]
pub enum OutTensor<'a> {
    F32(Vec<usize>, Cow<'a, [f32]>),
    F16(Vec<usize>, Vec<half::f16>),
    I64(Vec<usize>, Vec<i64>),
    U8(Vec<usize>, Cow<'a, [u8]>),
}

impl OutTensor<'_> {
    pub fn f32<T: Real>(t: &Tensor<T>) -> OutTensor<'static> {
        OutTensor::F32(
            t.shape().to_vec(),
            Cow::Owned(t.data().iter().map(|v| v.to_f32()).collect()),
        )
    }

    /// The tensor rounded to f16 (to nearest).
    pub fn f16<T: Real>(t: &Tensor<T>) -> OutTensor<'static> {
        OutTensor::F16(
            t.shape().to_vec(),
            t.data()
                .iter()
                .map(|v| half::f16::from_f32(v.to_f32()))
                .collect(),
        )
    }
}

fn f32_bytes(v: &[f32]) -> Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        Cow::Borrowed(bytemuck::cast_slice(v))
    } else {
        Cow::Owned(v.iter().flat_map(|x| x.to_le_bytes()).collect())
    }
}

impl View for &OutTensor<'_> {
    fn dtype(&self) -> Dtype {
        match self {
            OutTensor::F32(..) => Dtype::F32,
            OutTensor::F16(..) => Dtype::F16,
            OutTensor::I64(..) => Dtype::I64,
            OutTensor::U8(..) => Dtype::U8,
        }
    }
    fn shape(&self) -> &[usize] {
        match self {
            OutTensor::F32(s, _)
            | OutTensor::F16(s, _)
            | OutTensor::I64(s, _)
            | OutTensor::U8(s, _) => s,
        }
    }
    fn data(&self) -> Cow<'_, [u8]> {
        match self {
            OutTensor::F32(_, v) => f32_bytes(v),
            OutTensor::F16(_, v) => Cow::Owned(v.iter().flat_map(|x| x.to_le_bytes()).collect()),
            OutTensor::I64(_, v) => Cow::Owned(v.iter().flat_map(|x| x.to_le_bytes()).collect()),
            OutTensor::U8(_, v) => Cow::Borrowed(v),
        }
    }
    fn data_len(&self) -> usize {
        match self {
            OutTensor::F32(_, v) => v.len() * 4,
            OutTensor::F16(_, v) => v.len() * 2,
            OutTensor::I64(_, v) => v.len() * 8,
            OutTensor::U8(_, v) => v.len(),
        }
    }
}

/// Serialises tensors and metadata to bytes. The header is canonical (keys sorted), so the
/// same tensors and metadata always give the same bytes.
pub fn to_bytes(
    tensors: &BTreeMap<String, OutTensor<'_>>,
    metadata: HashMap<String, String>,
) -> Result<Vec<u8>> {
    let bytes =
        safetensors::serialize(tensors.iter().map(|(k, v)| (k.as_str(), v)), Some(metadata))
            .map_err(|e| Error::Format {
                what: "serialising".into(),
                detail: e.to_string(),
            })?;
    Ok(canonical_header(bytes))
}

/// Rewrites a safetensors header with its JSON keys sorted (safetensors writes its metadata
/// map in hash order, which differs between runs). Data offsets are relative to the data
/// section, so only the header and its length change.
fn canonical_header(bytes: Vec<u8>) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8-byte length")) as usize;
    let header: serde_json::Value =
        serde_json::from_slice(&bytes[8..8 + n]).expect("safetensors wrote valid JSON");
    // serde_json's map is ordered by key (no preserve_order feature).
    let mut json = serde_json::to_vec(&header).expect("serialisable");
    while !json.len().is_multiple_of(8) {
        json.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + json.len() + bytes.len() - 8 - n);
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(&json);
    out.extend_from_slice(&bytes[8 + n..]);
    out
}

pub(super) fn save(
    path: &Path,
    tensors: &BTreeMap<String, OutTensor<'_>>,
    metadata: HashMap<String, String>,
) -> Result<()> {
    write_atomic(path, &to_bytes(tensors, metadata)?)
}
