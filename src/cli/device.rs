//! The one place where the compute device (burn backend) is chosen.
//!
//! `CAC_DEVICE` names it:
//! * unset or `cpu`: the CPU. In a default build that is burn's pure-Rust `flex` backend with
//!   cac's own kernels; in a build with `--features tch` (the fast path) it is libtorch's CPU
//!   kernels, through burn's LibTorch backend.
//! * `flex`: the pure-Rust backend in any build (to compare the two paths in one binary).
//! * `cuda`: libtorch on the first CUDA GPU (`tch` builds; the pip wheel brings CUDA).
//! * `gpu`: burn's wgpu backend on Vulkan (`gpu` builds).
//!
//! See docs/detectors.md ("Backends", "The libtorch fast path").

/// The backends a build can run on, as `CAC_DEVICE` names them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// burn's Flex with cac's kernels (always built).
    Flex,
    /// libtorch on the CPU (`tch` feature).
    Torch,
    /// libtorch on CUDA device 0 (`tch` feature).
    TorchCuda,
    /// burn's wgpu on Vulkan (`gpu` feature).
    Wgpu,
}

impl Backend {
    /// The name used in tables and in `CAC_DEVICE`.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Flex => "flex",
            Backend::Torch => "libtorch",
            Backend::TorchCuda => "cuda",
            Backend::Wgpu => "gpu",
        }
    }

    /// Parses a `CAC_DEVICE` / `--backends` value; refuses a backend this binary lacks, saying
    /// which feature builds it.
    pub fn parse(v: &str) -> Result<Backend, String> {
        let b = match v.trim().to_ascii_lowercase().as_str() {
            "" | "cpu" => return Ok(Backend::cpu()),
            "flex" => Backend::Flex,
            "libtorch" | "torch" | "tch" => Backend::Torch,
            "cuda" => Backend::TorchCuda,
            "gpu" | "wgpu" | "vulkan" => Backend::Wgpu,
            other => {
                return Err(format!(
                    "unknown device {other:?}: use cpu, flex, libtorch, cuda (`--features tch` \
                     builds) or gpu (`--features gpu` builds)"
                ))
            }
        };
        let (built, feature) = match b {
            Backend::Flex => (true, ""),
            Backend::Torch | Backend::TorchCuda => (cfg!(feature = "tch"), "tch"),
            Backend::Wgpu => (cfg!(feature = "gpu"), "gpu"),
        };
        match built {
            true => Ok(b),
            false => Err(format!(
                "device {v:?} needs a binary built with `--features {feature}` (this one was not)"
            )),
        }
    }

    /// The CPU backend of this build: libtorch where built in, else Flex.
    pub fn cpu() -> Backend {
        match cfg!(feature = "tch") {
            true => Backend::Torch,
            false => Backend::Flex,
        }
    }

    /// The CPU backends this build has, the pure-Rust one first.
    pub fn cpus() -> Vec<Backend> {
        match cfg!(feature = "tch") {
            true => vec![Backend::Flex, Backend::Torch],
            false => vec![Backend::Flex],
        }
    }

    /// Its inference device (no gradient tracking).
    #[allow(deprecated)] // burn 0.22 marks LibTorch deprecated: chosen all the same (docs/detectors.md)
    pub fn device(self) -> burn::tensor::Device {
        match self {
            Backend::Flex => burn::tensor::Device::from(burn::backend::FlexDevice),
            #[cfg(feature = "tch")]
            Backend::Torch => {
                set_threads(rayon::current_num_threads());
                burn::tensor::Device::from(burn::backend::LibTorchDevice::Cpu)
            }
            #[cfg(feature = "tch")]
            Backend::TorchCuda => {
                if !tch::Cuda::is_available() {
                    eprintln!(
                        "error: CAC_DEVICE=cuda, but libtorch sees no CUDA device (driver \
                         missing, or no GPU). Unset CAC_DEVICE to run on the CPU."
                    );
                    std::process::exit(2);
                }
                burn::tensor::Device::from(burn::backend::LibTorchDevice::Cuda(0))
            }
            #[cfg(feature = "gpu")]
            Backend::Wgpu => {
                use burn::backend::{WgpuBackend, WgpuDevice, WgpuDeviceKind};
                let dev = WgpuDevice::new(WgpuDeviceKind::DefaultDevice).on(WgpuBackend::Vulkan);
                let dev = burn::tensor::Device::from(dev);
                static PROBED: std::sync::OnceLock<()> = std::sync::OnceLock::new();
                PROBED.get_or_init(|| probe(&dev));
                dev
            }
            #[allow(unreachable_patterns)]
            other => unreachable!("{other:?} is refused by Backend::parse in this build"),
        }
    }
}

/// libtorch's intra-op thread count (its own pool, not rayon's): the benchmarks set it per row,
/// the device sets it to rayon's pool size (`RAYON_NUM_THREADS`) so one variable governs both.
#[cfg(feature = "tch")]
pub fn set_threads(n: usize) {
    tch::set_num_threads(n.max(1) as i32);
}

/// Without libtorch there is no other pool to size.
#[cfg(not(feature = "tch"))]
pub fn set_threads(_n: usize) {}

/// The backend `CAC_DEVICE` asks for; a value naming no backend of this build exits with a
/// clear error (exit code 2) rather than running somewhere the user did not ask for.
pub fn backend() -> Backend {
    static CHOSEN: std::sync::OnceLock<Backend> = std::sync::OnceLock::new();
    *CHOSEN.get_or_init(|| {
        let v = std::env::var("CAC_DEVICE").unwrap_or_default();
        Backend::parse(&v).unwrap_or_else(|e| {
            eprintln!("error: CAC_DEVICE: {e}");
            std::process::exit(2)
        })
    })
}

/// The inference device (no gradient tracking).
pub fn inference() -> burn::tensor::Device {
    backend().device()
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

#[cfg(test)]
mod tests {
    use super::Backend;

    #[test]
    fn device_names_parse_and_unbuilt_backends_are_refused() {
        assert_eq!(Backend::parse("flex"), Ok(Backend::Flex));
        assert_eq!(Backend::parse(""), Ok(Backend::cpu()));
        assert_eq!(Backend::parse("CPU"), Ok(Backend::cpu()));
        let e = Backend::parse("tpu").unwrap_err();
        assert!(e.contains("unknown device") && e.contains("flex"), "{e}");
        match cfg!(feature = "tch") {
            true => assert_eq!(Backend::parse("cuda"), Ok(Backend::TorchCuda)),
            false => {
                let e = Backend::parse("libtorch").unwrap_err();
                assert!(e.contains("--features tch"), "{e}");
            }
        }
        if !cfg!(feature = "gpu") {
            assert!(Backend::parse("gpu")
                .unwrap_err()
                .contains("--features gpu"));
        }
        assert_eq!(Backend::cpus()[0], Backend::Flex);
    }
}
