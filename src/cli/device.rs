//! The one place where the compute device (burn backend) is chosen.
//!
//! By default: the CPU `flex` backend (the fastest CPU backend of burn 0.22 that builds offline).
//! Built with `--features gpu`, `CAC_DEVICE=gpu` selects burn's wgpu backend on Vulkan (any GPU
//! with a Vulkan driver, NVIDIA included); without the variable the CPU stays the default, so a
//! GPU build still runs on a machine without a GPU. See docs/detectors.md ("Backends").

/// Which device `CAC_DEVICE` asks for.
fn wants_gpu() -> bool {
    match std::env::var("CAC_DEVICE") {
        Ok(v) if v.eq_ignore_ascii_case("gpu") => true,
        Ok(v) if v.eq_ignore_ascii_case("cpu") || v.is_empty() => false,
        Ok(v) => {
            eprintln!("warning: CAC_DEVICE={v:?} is neither 'cpu' nor 'gpu'; using the CPU");
            false
        }
        Err(_) => false,
    }
}

/// The inference device (no gradient tracking).
pub fn inference() -> burn::tensor::Device {
    if wants_gpu() {
        #[cfg(feature = "gpu")]
        {
            use burn::backend::{WgpuBackend, WgpuDevice, WgpuDeviceKind};
            let dev = WgpuDevice::new(WgpuDeviceKind::DefaultDevice).on(WgpuBackend::Vulkan);
            return burn::tensor::Device::from(dev);
        }
        #[cfg(not(feature = "gpu"))]
        {
            eprintln!(
                "warning: CAC_DEVICE=gpu, but this binary was built without `--features gpu`; \
                 using the CPU"
            );
        }
    }
    burn::tensor::Device::from(burn::backend::FlexDevice)
}

/// The training device: autodiff on top of the inference device.
#[allow(dead_code)]
pub fn training() -> burn::tensor::Device {
    burn::tensor::Device::autodiff(inference())
}
