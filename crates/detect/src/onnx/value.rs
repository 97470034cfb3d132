//! The values on an ONNX graph's edges: float activations on the device ([`Dev`], logical rank
//! 0..=6 held as a rank-6 burn tensor with leading 1s, so every op is a burn op and autodiff
//! reaches the graph input) and small host tensors ([`Host`]: shapes, indices, constants, the
//! int64 arithmetic of exported shape computations, through `ndarray`). Not here: op semantics.

use anyhow::{anyhow, bail, Result};
use burn::tensor::{Device, Tensor, TensorData};
use ndarray::{ArrayD, IxDyn};

/// The largest logical rank the executor holds (YOLOv5's head uses rank 5).
pub(crate) const MAX_RANK: usize = 6;

/// A shape padded with leading 1s to [`MAX_RANK`].
pub(crate) fn pad6(shape: &[usize]) -> [usize; MAX_RANK] {
    let mut out = [1usize; MAX_RANK];
    out[MAX_RANK - shape.len()..].copy_from_slice(shape);
    out
}

/// A float tensor on the device with its logical shape.
#[derive(Clone, Debug)]
pub struct Dev {
    pub t: Tensor<MAX_RANK>,
    pub shape: Vec<usize>,
}

impl Dev {
    /// Wraps `t` (any rank) as a value of logical shape `shape` (same element count).
    pub fn new<const D: usize>(t: Tensor<D>, shape: Vec<usize>) -> Result<Self> {
        if shape.len() > MAX_RANK {
            bail!("rank {} > {MAX_RANK} is not supported", shape.len());
        }
        Ok(Dev {
            t: t.reshape(pad6(&shape)),
            shape,
        })
    }
    /// A value from a tensor whose dims are its logical shape.
    pub fn from<const D: usize>(t: Tensor<D>) -> Result<Self> {
        let shape = t.dims().to_vec();
        Self::new(t, shape)
    }
    pub fn rank(&self) -> usize {
        self.shape.len()
    }
    /// The physical axis of logical axis `a`.
    pub fn axis(&self, a: usize) -> usize {
        MAX_RANK - self.rank() + a
    }
    /// The value as a rank-4 tensor (rank <= 4; leading 1s added).
    pub(crate) fn t4(&self) -> Result<Tensor<4>> {
        if self.rank() > 4 {
            bail!("expected rank <= 4, got shape {:?}", self.shape);
        }
        let mut s = [1usize; 4];
        s[4 - self.rank()..].copy_from_slice(&self.shape);
        Ok(self.t.clone().reshape(s))
    }
    /// Host copy of the values (row-major).
    pub fn to_vec(&self) -> Result<Vec<f32>> {
        self.t
            .to_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .map_err(|e| anyhow!("cannot read tensor values: {e:?}"))
    }
    pub fn to_host(&self) -> Result<Host> {
        Ok(Host::F(ArrayD::from_shape_vec(
            IxDyn(&self.shape),
            self.to_vec()?,
        )?))
    }
}

/// A tensor on the host; every integer and boolean type is widened to i64.
#[derive(Clone, Debug, PartialEq)]
pub enum Host {
    F(ArrayD<f32>),
    I(ArrayD<i64>),
}

impl Host {
    pub fn shape(&self) -> &[usize] {
        match self {
            Host::F(a) => a.shape(),
            Host::I(a) => a.shape(),
        }
    }
    pub fn len(&self) -> usize {
        self.shape().iter().product()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Values as i64 (floats truncated toward zero), row-major.
    pub(crate) fn ints(&self) -> Vec<i64> {
        match self {
            Host::I(a) => a.iter().copied().collect(),
            Host::F(a) => a.iter().map(|&v| v as i64).collect(),
        }
    }
    /// Values as f32, row-major.
    pub fn floats(&self) -> Vec<f32> {
        match self {
            Host::F(a) => a.iter().copied().collect(),
            Host::I(a) => a.iter().map(|&v| v as f32).collect(),
        }
    }
    pub(crate) fn as_f(&self) -> ArrayD<f32> {
        match self {
            Host::F(a) => a.clone(),
            Host::I(a) => a.mapv(|v| v as f32),
        }
    }
    /// Uploads the values as a float tensor on `dev`.
    pub fn to_dev(&self, dev: &Device) -> Result<Dev> {
        let v = self.floats();
        let n = v.len();
        Dev::new(
            Tensor::<1>::from_data(TensorData::new(v, [n]), dev),
            self.shape().to_vec(),
        )
    }
    pub(crate) fn scalar_i(v: i64) -> Host {
        Host::I(ArrayD::from_elem(IxDyn(&[]), v))
    }
    pub(crate) fn vec_i(v: Vec<i64>) -> Host {
        let n = v.len();
        Host::I(ArrayD::from_shape_vec(IxDyn(&[n]), v).expect("1-D"))
    }
}

/// A value on an edge.
#[derive(Clone, Debug)]
pub enum Val {
    D(Dev),
    H(Host),
}

impl Val {
    pub fn shape(&self) -> &[usize] {
        match self {
            Val::D(d) => &d.shape,
            Val::H(h) => h.shape(),
        }
    }
    /// The value as a device float tensor (host values are uploaded).
    pub fn dev(&self, dev: &Device) -> Result<Dev> {
        match self {
            Val::D(d) => Ok(d.clone()),
            Val::H(h) => h.to_dev(dev),
        }
    }
    /// The value on the host (device values are read back: no gradient flows through).
    pub fn host(&self) -> Result<Host> {
        match self {
            Val::D(d) => d.to_host(),
            Val::H(h) => Ok(h.clone()),
        }
    }
}
