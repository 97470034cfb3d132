//! The one place where the compute device (burn backend) is chosen: the CPU `flex` backend,
//! with or without autodiff.

/// The inference device (no gradient tracking).
pub fn inference() -> burn::tensor::Device {
    burn::tensor::Device::from(burn::backend::FlexDevice)
}

/// The training device: autodiff on top of the CPU backend.
#[allow(dead_code)]
pub fn training() -> burn::tensor::Device {
    burn::tensor::Device::autodiff(inference())
}
