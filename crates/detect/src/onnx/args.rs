//! What an op implementation reads: a node's inputs ([`Args`]: device or host values, omitted
//! optional inputs) and attributes, with numpy broadcasting and axis normalisation shared by the
//! elementwise, shape and layer ops. Not here: any op's semantics.

use super::model::{Attr, NodeDef};
use super::value::{pad6, Dev, Val, MAX_RANK};
use anyhow::{anyhow, ensure, Result};
use burn::tensor::{Device, Tensor};

/// A node's inputs and attributes, as the op implementations read them.
pub struct Args<'a> {
    pub node: &'a NodeDef,
    pub opset: i64,
    pub dev: &'a Device,
    pub args: &'a [Option<&'a Val>],
}

impl<'a> Args<'a> {
    pub fn opt(&self, k: usize) -> Option<&'a Val> {
        self.args.get(k).copied().flatten()
    }
    pub fn input(&self, k: usize) -> Result<&'a Val> {
        self.opt(k).ok_or_else(|| anyhow!("missing input {k}"))
    }
    pub(crate) fn n_inputs(&self) -> usize {
        self.args.len()
    }
    /// Input `k` as a device float tensor.
    pub(crate) fn dev_input(&self, k: usize) -> Result<Dev> {
        self.input(k)?.dev(self.dev)
    }
    /// Input `k` as host integers (shape, axis, size arguments); `None` when omitted.
    pub(crate) fn ints_input(&self, k: usize) -> Result<Option<Vec<i64>>> {
        Ok(match self.opt(k) {
            None => None,
            Some(Val::H(h)) => Some(h.ints()),
            Some(Val::D(d)) => {
                ensure!(
                    d.shape.iter().product::<usize>() <= 64,
                    "input {k} must be a small constant (shape/axis argument), got shape {:?}",
                    d.shape
                );
                Some(d.to_host()?.ints())
            }
        })
    }
    pub(crate) fn attr(&self, key: &str) -> Option<&'a Attr> {
        self.node.attrs.get(key)
    }
    pub fn f(&self, key: &str) -> Option<f32> {
        match self.attr(key)? {
            Attr::F(v) => Some(*v),
            Attr::I(v) => Some(*v as f32),
            _ => None,
        }
    }
    pub fn i(&self, key: &str) -> Option<i64> {
        match self.attr(key)? {
            Attr::I(v) => Some(*v),
            _ => None,
        }
    }
    pub(crate) fn ints(&self, key: &str) -> Option<Vec<i64>> {
        match self.attr(key)? {
            Attr::Is(v) => Some(v.clone()),
            Attr::I(v) => Some(vec![*v]),
            _ => None,
        }
    }
    pub fn floats(&self, key: &str) -> Option<Vec<f32>> {
        match self.attr(key)? {
            Attr::Fs(v) => Some(v.clone()),
            Attr::F(v) => Some(vec![*v]),
            _ => None,
        }
    }
    pub fn s(&self, key: &str) -> Option<&'a str> {
        match self.attr(key)? {
            Attr::S(v) => Some(v.as_str()),
            _ => None,
        }
    }
    pub(crate) fn n_outputs(&self) -> usize {
        self.node.outputs.len()
    }
}

pub use crate::kernels::broadcast_shape as broadcast;

/// The physical tensor of `d` broadcast to logical shape `out`.
pub fn expand(d: &Dev, out: &[usize]) -> Tensor<MAX_RANK> {
    if d.shape == out {
        d.t.clone()
    } else {
        d.t.clone().expand(pad6(out))
    }
}

/// A possibly negative axis of a rank-`rank` tensor, checked.
pub fn axis(a: i64, rank: usize) -> Result<usize> {
    let r = rank as i64;
    ensure!(
        (-r..r).contains(&a) || (rank == 0 && a == 0),
        "axis {a} is out of range for rank {rank}"
    );
    Ok(if a < 0 { (a + r) as usize } else { a as usize })
}
