//! The host's side of a tensor: its values as a `Vec`, and whether a device computes on the
//! host's CPU cores.

use anyhow::Result;
use burn::tensor::{Device, Tensor};

/// Host copy of a float tensor's values.
pub fn to_vec<const D: usize>(t: &Tensor<D>) -> Result<Vec<f32>> {
    t.to_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("cannot read tensor values: {e:?}"))
}

/// Whether `device` (or the device an autodiff device wraps) computes on the host's CPU cores:
/// Flex, or libtorch's CPU. Work put on other threads then competes with the detectors for the
/// same cores; beside a GPU it runs in the time the cores are idle.
#[allow(deprecated)] // burn 0.22 marks LibTorch deprecated: chosen all the same (docs/detectors.md)
pub fn computes_on_host(device: &Device) -> bool {
    use burn::backend::DispatchDevice;
    match device.as_dispatch().clone().inner() {
        DispatchDevice::Flex(_) => true,
        #[cfg(feature = "tch")]
        DispatchDevice::LibTorch(d) => d == burn::backend::LibTorchDevice::Cpu,
        #[allow(unreachable_patterns)]
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Flex is the host's, through autodiff too (libtorch's devices: tests/libtorch.rs).
    #[test]
    fn host_devices_are_told_apart_through_autodiff() {
        let flex = Device::from(burn::backend::FlexDevice);
        assert!(computes_on_host(&flex));
        assert!(computes_on_host(&Device::autodiff(flex)));
    }
}
