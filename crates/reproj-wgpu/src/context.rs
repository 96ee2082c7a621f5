//! Device creation, kept apart from the kernels so that callers (and tests) can bring their own
//! `wgpu::Device` (see [`crate::Reprojector::with_device`]).

use std::sync::{Arc, OnceLock};

use crate::error::{GpuError, Result};

/// How [`GpuContext::new`] picks its device.
#[derive(Debug, Clone)]
pub struct ContextOptions {
    /// Request 64-bit atomic min/max (`SHADER_INT64` + `SHADER_INT64_ATOMIC_MIN_MAX`) when the
    /// adapter offers them. Default true; without them the splat uses the 32-bit two-pass variant.
    pub int64_atomics: bool,
    /// The power preference passed to the adapter request. Default high performance.
    pub power_preference: wgpu::PowerPreference,
}

impl Default for ContextOptions {
    fn default() -> Self {
        ContextOptions {
            int64_atomics: true,
            power_preference: wgpu::PowerPreference::HighPerformance,
        }
    }
}

/// A wgpu device and queue with the adapter's description.
#[derive(Debug, Clone)]
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter it was created from.
    pub info: wgpu::AdapterInfo,
    /// Whether (and why) the device was lost.
    pub loss: DeviceLoss,
}

/// Whether a device was lost, and why: set by the device's lost callback ([`DeviceLoss::watch`]).
///
/// On a lost device wgpu reports no errors (as WebGPU specifies): what is made on it is invalid,
/// and a buffer made invalid that way panics when it is mapped. So every operation of
/// [`crate::Reprojector`] and [`crate::Uploader`] asks this first ([`DeviceLoss::check`]), and
/// turns the errors that follow a loss into [`GpuError::Lost`] ([`DeviceLoss::explain`]).
#[derive(Debug, Clone, Default)]
pub struct DeviceLoss(Option<Arc<OnceLock<String>>>);

impl DeviceLoss {
    /// Watches `device` (its lost callback, which replaces any other).
    pub fn watch(device: &wgpu::Device) -> DeviceLoss {
        let cell = Arc::new(OnceLock::new());
        let set = cell.clone();
        device.set_device_lost_callback(move |reason, message| {
            let _ = set.set(if message.is_empty() {
                format!("{reason:?}")
            } else {
                format!("{reason:?}: {message}")
            });
        });
        DeviceLoss(Some(cell))
    }

    /// Why the device was lost, or `None` while it is not known to be (or it is not watched:
    /// [`DeviceLoss::default`]).
    pub fn reason(&self) -> Option<&str> {
        self.0.as_ref()?.get().map(String::as_str)
    }

    /// [`GpuError::Lost`] once `device` (the watched one) is known to be lost. wgpu calls the
    /// lost callback while it polls the device, so a watched device is polled first, without
    /// waiting: a loss the driver reported is found then; a destroyed device is lost only once
    /// its queue is empty ([`DeviceLoss::check_drained`]).
    pub fn check(&self, device: &wgpu::Device) -> Result<()> {
        self.poll_and_check(device, wgpu::PollType::Poll)
    }

    /// [`DeviceLoss::check`] after the work submitted to `device` is done: what a destroyed
    /// device needs before it counts as lost (wgpu, `Device::maintain`).
    pub fn check_drained(&self, device: &wgpu::Device) -> Result<()> {
        self.poll_and_check(device, wgpu::PollType::Wait)
    }

    fn poll_and_check(&self, device: &wgpu::Device, poll: wgpu::PollType) -> Result<()> {
        if self.0.is_some() {
            let _ = device.poll(poll);
        }
        match self.reason() {
            Some(why) => Err(GpuError::Lost(why.to_owned())),
            None => Ok(()),
        }
    }

    /// `r`, with a device error that came from the loss of `device` said as such (found after
    /// the device's work is done: an error path can wait).
    pub fn explain<T>(&self, device: &wgpu::Device, r: Result<T>) -> Result<T> {
        match r {
            Err(GpuError::Device(_) | GpuError::State(_)) => self.check_drained(device).and(r),
            r => r,
        }
    }
}

/// The features the 64-bit splat needs.
pub fn int64_atomic_features() -> wgpu::Features {
    wgpu::Features::SHADER_INT64 | wgpu::Features::SHADER_INT64_ATOMIC_MIN_MAX
}

impl GpuContext {
    /// Creates a device on the best adapter: native backends (Vulkan, Metal, DX12; `WGPU_BACKEND`
    /// overrides), the adapter's own limits (large images need storage bindings above the WebGPU
    /// defaults), and 64-bit atomic min/max when offered and asked for.
    ///
    /// Validation errors of the device are captured by error scopes around every operation of
    /// [`crate::Reprojector`]; any that escape are written to stderr, never turned into a panic.
    ///
    /// # Errors
    /// [`GpuError::NoAdapter`] when no adapter exists or the device cannot be created.
    pub fn new(options: &ContextOptions) -> Result<GpuContext> {
        pollster::block_on(Self::new_async(options))
    }

    async fn new_async(options: &ContextOptions) -> Result<GpuContext> {
        let env = std::env::var("WGPU_BACKEND").ok();
        if let Some(v) = &env {
            check_backend_env(v)?;
        }
        let mut desc = wgpu::InstanceDescriptor::from_env_or_default();
        if env.is_none() {
            desc.backends = wgpu::Backends::PRIMARY;
        }
        let instance = wgpu::Instance::new(&desc);
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: options.power_preference,
                force_fallback_adapter: false,
                compatible_surface: None,
            })
            .await
            .map_err(|e| match &env {
                Some(v) => GpuError::NoAdapter(format!(
                    "{e} (WGPU_BACKEND = {v:?} limits the search to those backends)"
                )),
                None => GpuError::NoAdapter(e.to_string()),
            })?;
        let info = adapter.get_info();
        let wanted = int64_atomic_features();
        let features = if options.int64_atomics && adapter.features().contains(wanted) {
            wanted
        } else {
            wgpu::Features::empty()
        };
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("reproj-wgpu"),
                required_features: features,
                required_limits: adapter.limits(),
                memory_hints: wgpu::MemoryHints::Performance,
                trace: wgpu::Trace::Off,
            })
            .await
            .map_err(|e| {
                GpuError::NoAdapter(format!("adapter '{}' gave no device: {e}", info.name))
            })?;
        device.on_uncaptured_error(Box::new(|e| {
            eprintln!("reproj-wgpu: uncaptured wgpu error: {e}");
        }));
        Ok(GpuContext {
            loss: DeviceLoss::watch(&device),
            device,
            queue,
            info,
        })
    }

    /// Whether the device has 64-bit atomic min/max.
    pub fn int64_atomics(&self) -> bool {
        self.device.features().contains(int64_atomic_features())
    }

    /// The adapter in words, e.g. `llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, Cpu, Mesa 22.3.6)`.
    pub fn describe(&self) -> String {
        describe(&self.info)
    }
}

/// The names wgpu 26 reads from `WGPU_BACKEND` (`wgpu::Backends::from_comma_list`), in groups.
const BACKEND_NAMES: [&[&str]; 6] = [
    &["vulkan", "vk"],
    &["metal", "mtl"],
    &["dx12", "d3d12"],
    &["gl", "gles", "opengl"],
    &["webgpu"],
    &["noop"],
];

/// Refuses a `WGPU_BACKEND` with a name wgpu does not know: wgpu skips such names (with a log
/// line nobody sees), so a typo or an empty value selected no backend, and the error that followed
/// told the caller to install a Vulkan driver.
fn check_backend_env(value: &str) -> Result<()> {
    let unknown: Vec<&str> = value
        .split(',')
        .map(str::trim)
        .filter(|b| {
            !BACKEND_NAMES
                .iter()
                .any(|names| names.contains(&b.to_lowercase().as_str()))
        })
        .collect();
    if unknown.is_empty() {
        return Ok(());
    }
    Err(GpuError::Config(format!(
        "WGPU_BACKEND = {value:?} names no wgpu backend in {unknown:?}; expected a \
         comma-separated list of vulkan, metal, dx12, gl (or unset it for the platform's \
         native backends)"
    )))
}

/// An adapter in words.
pub fn describe(info: &wgpu::AdapterInfo) -> String {
    let mut s = format!("{} ({:?}, {:?}", info.name, info.backend, info.device_type);
    if !info.driver_info.is_empty() {
        s.push_str(", ");
        s.push_str(&info.driver_info);
    }
    s.push(')');
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backend_env_names_are_checked() {
        for ok in ["vulkan", "Vulkan, GL", "vk,metal", "dx12", "noop"] {
            assert_eq!(check_backend_env(ok), Ok(()), "{ok}");
        }
        for bad in ["vulkna", "", "vulkan,", "primary"] {
            let Err(GpuError::Config(msg)) = check_backend_env(bad) else {
                panic!("{bad:?} was accepted");
            };
            assert!(msg.contains(&format!("WGPU_BACKEND = {bad:?}")), "{msg}");
            assert!(
                msg.contains("expected a comma-separated list of vulkan"),
                "{msg}"
            );
        }
    }
}
