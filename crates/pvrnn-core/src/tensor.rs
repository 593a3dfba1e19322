//! A minimal owned, row-major, n-dimensional array: the unit of storage, I/O and optimisation.

use crate::{Real, error::Error, error::Result};

/// Row-major n-dimensional array.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Tensor<T> {
    shape: Vec<usize>,
    data: Vec<T>,
}

impl<T: Real> Tensor<T> {
    pub fn zeros(shape: &[usize]) -> Self {
        Self {
            shape: shape.to_vec(),
            data: vec![T::ZERO; shape.iter().product()],
        }
    }

    pub fn from_vec(shape: &[usize], data: Vec<T>) -> Result<Self> {
        let n: usize = shape.iter().product();
        if n != data.len() {
            return Err(Error::InvalidArgument(format!(
                "tensor of shape {shape:?} needs {n} values, got {}",
                data.len()
            )));
        }
        Ok(Self {
            shape: shape.to_vec(),
            data,
        })
    }

    pub fn shape(&self) -> &[usize] {
        &self.shape
    }
    pub fn data(&self) -> &[T] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }
    pub fn into_data(self) -> Vec<T> {
        self.data
    }
    pub fn len(&self) -> usize {
        self.data.len()
    }
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// The sub-array at `index` of the leading axes, as a flat slice.
    pub fn sub(&self, index: &[usize]) -> &[T] {
        let (start, len) = self.sub_range(index);
        &self.data[start..start + len]
    }
    pub fn sub_mut(&mut self, index: &[usize]) -> &mut [T] {
        let (start, len) = self.sub_range(index);
        &mut self.data[start..start + len]
    }
    fn sub_range(&self, index: &[usize]) -> (usize, usize) {
        assert!(index.len() <= self.shape.len());
        let len: usize = self.shape[index.len()..].iter().product();
        let mut start = 0;
        for (axis, &i) in index.iter().enumerate() {
            assert!(
                i < self.shape[axis],
                "index {i} out of range for axis {axis}"
            );
            start = start * self.shape[axis] + i;
        }
        (start * len, len)
    }

    /// The same values in another float type.
    pub fn cast<U: Real>(&self) -> Tensor<U> {
        Tensor {
            shape: self.shape.clone(),
            data: self.data.iter().map(|&v| U::from_f64(v.to_f64())).collect(),
        }
    }

    /// Flat index and value of the first non-finite entry, if any.
    pub fn first_non_finite(&self) -> Option<(usize, T)> {
        self.data
            .iter()
            .position(|v| !v.is_finite())
            .map(|i| (i, self.data[i]))
    }

    /// Multi-index of a flat index.
    pub fn unravel(&self, mut flat: usize) -> Vec<usize> {
        let mut index = vec![0; self.shape.len()];
        for axis in (0..self.shape.len()).rev() {
            index[axis] = flat % self.shape[axis];
            flat /= self.shape[axis];
        }
        index
    }
}
