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

/// Whether the device in use is the GPU (the `gpu` feature, asked for with `CAC_DEVICE=gpu`).
pub fn is_gpu() -> bool {
    cfg!(feature = "gpu") && wants_gpu()
}

/// The inference device (no gradient tracking).
pub fn inference() -> burn::tensor::Device {
    if wants_gpu() {
        #[cfg(feature = "gpu")]
        {
            use burn::backend::{WgpuBackend, WgpuDevice, WgpuDeviceKind};
            let dev = WgpuDevice::new(WgpuDeviceKind::DefaultDevice).on(WgpuBackend::Vulkan);
            let dev = burn::tensor::Device::from(dev);
            static PROBED: std::sync::OnceLock<()> = std::sync::OnceLock::new();
            PROBED.get_or_init(|| probe(&dev));
            return dev;
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

/// Runs one tiny op on the GPU; where no Vulkan device can be had (wgpu panics then), exits with
/// a clear error instead of a panic from a worker thread.
#[cfg(feature = "gpu")]
fn probe(dev: &burn::tensor::Device) {
    let hook = std::panic::take_hook();
    let message = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    let m = message.clone();
    std::panic::set_hook(Box::new(move |info| {
        let mut m = m.lock().unwrap_or_else(|e| e.into_inner());
        if m.is_empty() {
            *m = info.to_string();
        }
    }));
    let ok = std::panic::catch_unwind(|| {
        burn::tensor::Tensor::<1>::ones([1], dev).into_data();
    })
    .is_ok();
    std::panic::set_hook(hook);
    if !ok {
        let m = message.lock().unwrap_or_else(|e| e.into_inner()).clone();
        eprintln!(
            "error: CAC_DEVICE=gpu, but no GPU could be used through Vulkan (is a Vulkan driver \
             and libvulkan.so.1 installed?). Unset CAC_DEVICE to run on the CPU.\n  {m}"
        );
        std::process::exit(2);
    }
}

/// The training device: autodiff on top of the inference device.
#[allow(dead_code)]
pub fn training() -> burn::tensor::Device {
    burn::tensor::Device::autodiff(inference())
}
