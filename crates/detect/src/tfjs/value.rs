//! The values that flow along an imported graph's edges ([`FloatValue`] on the device, host
//! tensors for shapes and axes) and the resolved [`Node`]: the vocabulary that the executor
//! ([`super::graph`]), the op semantics ([`super::ops`]) and the rewrites ([`super::fuse`]) share.
//! Not here: planning or running a graph.

use super::model::{HostData, HostTensor, NodeDef};
use anyhow::{anyhow, Result};
use burn::tensor::Tensor;

/// A float tensor of logical rank 0..=4, stored as a rank-4 burn tensor with leading 1s.
///
/// A rank-4 NHWC value produced by a convolution may be held physically as NCHW
/// (`nchw = true`: `t` is the logical tensor permuted by `[0, 3, 1, 2]`), so that chains of
/// convolutions and elementwise ops never copy between layouts.
#[derive(Clone, Debug)]
pub struct FloatValue {
    pub t: Tensor<4>,
    pub shape: Vec<usize>,
    pub nchw: bool,
}

impl FloatValue {
    /// Wraps a tensor whose logical shape is `shape` (rank <= 4); reshapes to padded rank 4.
    pub fn new(t: Tensor<4>, shape: Vec<usize>) -> Self {
        debug_assert_eq!(
            t.dims().iter().product::<usize>(),
            shape.iter().product::<usize>()
        );
        let padded = pad4(&shape);
        let t = if t.dims() == padded {
            t
        } else {
            t.reshape(padded)
        };
        FloatValue {
            t,
            shape,
            nchw: false,
        }
    }
    /// A logical NHWC value from its physical NCHW tensor.
    pub(crate) fn from_nchw(t: Tensor<4>) -> Self {
        let [n, c, h, w] = t.dims();
        FloatValue {
            t,
            shape: vec![n, h, w, c],
            nchw: true,
        }
    }
    /// The physical NCHW tensor of a rank-4 NHWC value (also aligns a broadcastable
    /// lower-rank value, padded to rank 4, with NCHW-held values).
    pub(crate) fn to_nchw(&self) -> Tensor<4> {
        if self.nchw {
            self.t.clone()
        } else {
            self.t.clone().permute([0, 3, 1, 2])
        }
    }
    /// This value with `t` in plain logical layout.
    pub fn logical(self) -> Self {
        if self.nchw {
            FloatValue {
                t: self.t.permute([0, 2, 3, 1]),
                shape: self.shape,
                nchw: false,
            }
        } else {
            self
        }
    }
    /// A rank-4 value as it is.
    pub(crate) fn from4(t: Tensor<4>) -> Self {
        let shape = t.dims().to_vec();
        FloatValue {
            t,
            shape,
            nchw: false,
        }
    }
    pub fn rank(&self) -> usize {
        self.shape.len()
    }
    /// Offset of logical axis 0 in the physical rank-4 tensor.
    pub fn offset(&self) -> usize {
        4 - self.rank()
    }
    /// Host copy of the values (row-major, logical shape).
    pub fn to_host(&self) -> Result<HostTensor> {
        let v: Vec<f32> = self
            .clone()
            .logical()
            .t
            .to_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .map_err(|e| anyhow!("cannot read tensor values: {e:?}"))?;
        Ok(HostTensor {
            shape: self.shape.clone(),
            data: HostData::F32(v),
        })
    }
}

/// Pads a shape of rank <= 4 with leading 1s to rank 4.
pub(crate) fn pad4(shape: &[usize]) -> [usize; 4] {
    let mut out = [1usize; 4];
    let off = 4 - shape.len();
    out[off..].copy_from_slice(shape);
    out
}

/// A value flowing along a graph edge.
// Float is the common case; boxing it would add an allocation per edge.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub enum Value {
    Float(FloatValue),
    Host(HostTensor),
}

impl Value {
    pub fn shape(&self) -> &[usize] {
        match self {
            Value::Float(f) => &f.shape,
            Value::Host(h) => &h.shape,
        }
    }
}

/// A resolved node: its op, its inputs as (node index, output index), its attributes.
#[derive(Debug)]
pub struct Node {
    pub def: NodeDef,
    pub inputs: Vec<(usize, usize)>,
}

impl Node {
    pub fn name(&self) -> &str {
        &self.def.name
    }
    pub fn op(&self) -> &str {
        &self.def.op
    }
}
