//! [`Reprojector`]: the device-resident client reprojection.
//!
//! A pair of server frames is uploaded once ([`Reprojector::load`]); each client frame then uploads
//! only its pose-dependent uniforms (the client transfers, `α`) and, when asked, downloads the
//! image ([`Reprojector::render`]). A real-time client uploads the next pair on another thread
//! while this one renders ([`Uploader::upload`], from [`Reprojector::uploader`]) and makes it
//! current between two frames ([`Reprojector::install`], no copy), so that no display frame pays
//! the upload. Per client frame the GPU runs:
//!
//! 1. a buffer clear of the splat grid;
//! 2. pass 1, scene flow and splatting over every active source slot (one dispatch layer per slot;
//!    `splat64.wgsl`, or the two dispatches of `splat32.wgsl`);
//! 3. the auxiliary grids (`resolve.wgsl`, `aux_grid`, one layer per auxiliary camera);
//! 4. the resolve of every output pixel (`resolve.wgsl`, `resolve`).
//!
//! The semantics are reproj-core's ([`reproj_core::reproject()`] with `ours`, `ours_extrapolate`
//! and `forward_splat`), including its input checks and error messages; `tests/parity.rs`
//! compares the two on the built-in scenes.

use std::borrow::Cow;
use std::sync::{mpsc, Arc, Mutex};

use bytemuck::Zeroable;

use reproj_core::method::MAX_ALPHA;
use reproj_core::params::TILE;
use reproj_core::reproject::REFERENCE_SHORT_SIDE;
use reproj_core::{
    CameraView, Diagnostics, FrameView, Mat4, Method, NdcTransfer, Params, ReprojError, Request,
};

use crate::context::{int64_atomic_features, DeviceLoss, GpuContext};
use crate::error::{GpuError, Result};
use crate::layout::{
    pack_rgb, FrameSourceU, FrameU, SourceU, TexelU, TransferU, AUX_CELL_BYTES, DIAG_BYTES,
    FLOW_BYTES, MAX_SLOTS, OUT_BYTES, SPLAT_BYTES,
};
use crate::shaders::Module;

/// Most cameras per frame (main + 3 auxiliary): two frames fill the `MAX_SLOTS` source slots.
pub const MAX_CAMERAS: usize = MAX_SLOTS / 2;
/// Most output slots (e.g. one per eye) a reprojector keeps on the device.
pub const MAX_OUTPUTS: usize = 8;

/// How the splat keeps the nearest point per cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Atomics {
    /// One 64-bit atomic max per point (`SHADER_INT64_ATOMIC_MIN_MAX`).
    Int64,
    /// 32-bit atomics in two dispatches (depth, then index); the same result.
    Int32,
}

impl Atomics {
    /// `"int64"` or `"int32"`.
    pub fn name(self) -> &'static str {
        match self {
            Atomics::Int64 => "int64",
            Atomics::Int32 => "int32",
        }
    }
}

/// Options of a [`Reprojector`].
#[derive(Debug, Clone, Copy, Default)]
pub struct ReprojectorOptions {
    /// Use the 32-bit splat even where the device has 64-bit atomics (for tests and comparisons).
    pub force_32bit_atomics: bool,
}

/// What an output slot holds before a client frame is rendered into it: pixels without a match
/// keep it (seeds/000 §3.5 rule 3).
#[derive(Debug, Clone, Copy)]
pub enum Previous<'a> {
    /// What the slot holds on the device: the last frame rendered into it at this size (black when
    /// the slot is new or its size changed). Nothing is uploaded.
    Keep,
    /// Black.
    Black,
    /// This image (`H·W·3` RGB8 at the client camera's size), uploaded.
    Image(&'a [u8]),
}

/// Which pipeline runs, as reproj-core's `reproject::Mode`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Ours,
    ForwardSplat,
}

/// One source slot of the loaded pair.
#[derive(Debug, Clone, Copy)]
struct Slot {
    width: usize,
    height: usize,
    /// `P⁻¹` in `f64`, for the per-frame transfers (composed in `f64` as on the CPU).
    inv: Mat4,
}

/// A pair of server frames on the device ([`Uploader::upload`]): the texels of every source
/// slot and the uniforms that stay fixed while the pair is current. Made current with
/// [`Reprojector::install`]; the device memory is freed when the last handle is dropped.
#[derive(Debug)]
pub struct UploadedPair {
    slots: [Option<Slot>; MAX_SLOTS],
    n_aux: usize,
    /// Source points over every slot (the flow and splat scratch need as many entries).
    points: usize,
    /// Auxiliary cells (the newer frame's auxiliary cameras).
    cells: usize,
    texels: wgpu::Buffer,
    sources: wgpu::Buffer,
}

impl UploadedPair {
    /// Whether the pair holds the older frame (`F_t`), i.e. can interpolate.
    pub fn has_older(&self) -> bool {
        self.slots[0].is_some()
    }

    /// Bytes of device memory the pair holds (texels and uniforms).
    pub fn device_bytes(&self) -> u64 {
        self.texels.size() + self.sources.size()
    }
}

/// The per-frame working buffers of the current pair (written every client frame), kept across
/// pairs while they fit.
#[derive(Debug)]
struct Scratch {
    flow: wgpu::Buffer,
    splat: wgpu::Buffer,
    cells: wgpu::Buffer,
}

/// The current pair: what [`Reprojector::render`] reads.
#[derive(Debug)]
struct Current {
    pair: Arc<UploadedPair>,
    scratch: Scratch,
    /// Bumped on every install, so that output bind groups are rebuilt.
    generation: u64,
}

/// One output slot on the device.
#[derive(Debug)]
struct Output {
    width: usize,
    height: usize,
    rgb: wgpu::Buffer,
    diag: wgpu::Buffer,
    staging_rgb: wgpu::Buffer,
    staging_diag: wgpu::Buffer,
    bind_group: Option<(u64, wgpu::BindGroup)>,
}

/// The pass-1 pipelines.
#[derive(Debug)]
enum SplatPipelines {
    Int64(wgpu::ComputePipeline),
    Int32 {
        depth: wgpu::ComputePipeline,
        index: wgpu::ComputePipeline,
    },
}

/// The GPU twin of [`reproj_core::reproject()`] for `ours`, `ours_extrapolate` and `forward_splat`,
/// with the server frames kept on the device between client frames.
#[derive(Debug)]
pub struct Reprojector {
    device: wgpu::Device,
    queue: wgpu::Queue,
    atomics: Atomics,
    layout: wgpu::BindGroupLayout,
    splat: SplatPipelines,
    aux_grid: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    frame_ub: wgpu::Buffer,
    current: Option<Current>,
    /// The scratch of the last pair, kept for the next one after [`Reprojector::load`] drops it.
    spare: Option<Scratch>,
    outputs: Vec<Option<Output>>,
    generation: u64,
    loss: DeviceLoss,
}

/// Uploads pairs to a reprojector's device ([`Reprojector::uploader`]); cheap to clone, and usable
/// from any thread while the reprojector renders on another (wgpu's device and queue are shared
/// handles).
#[derive(Debug, Clone)]
pub struct Uploader {
    device: wgpu::Device,
    queue: wgpu::Queue,
    loss: DeviceLoss,
}

/// Error scopes are a stack per device in wgpu 26, not per thread: two threads inside
/// [`scoped`] at once would pop each other's scopes and report each other's errors. Every scoped
/// section in the process takes this lock; they are short (buffer creation, encoding and submitting
/// a frame), and an upload fills its buffers outside them ([`Uploader::upload`]).
static SCOPES: Mutex<()> = Mutex::new(());

/// Runs `f` inside validation and out-of-memory error scopes; an error of either becomes
/// [`GpuError::Device`] with `what` in front.
fn scoped<T>(device: &wgpu::Device, what: &str, f: impl FnOnce() -> Result<T>) -> Result<T> {
    // A panic cannot happen while the lock is held (`f` returns errors), but a poisoned lock
    // guards nothing that could be left inconsistent: take it anyway.
    let _one_at_a_time = SCOPES.lock().unwrap_or_else(|e| e.into_inner());
    device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    device.push_error_scope(wgpu::ErrorFilter::Validation);
    let r = f();
    let validation = pollster::block_on(device.pop_error_scope());
    let oom = pollster::block_on(device.pop_error_scope());
    if let Some(e) = oom.or(validation) {
        return Err(GpuError::Device(format!("{what}: {e}")));
    }
    r
}

fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn uniform(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// The bind group of every pass, as `shaders/shared/bindings.wgsl` and the modules declare it.
pub fn bind_group_layout_entries() -> [wgpu::BindGroupLayoutEntry; 8] {
    [
        uniform(0),        // frame
        uniform(1),        // sources
        storage(2, true),  // texels
        storage(3, false), // flow
        storage(4, false), // splat
        storage(5, false), // aux_cells
        storage(6, false), // out_rgb
        storage(7, false), // out_diag
    ]
}

fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}

fn div_ceil_u32(n: usize, d: usize) -> u32 {
    n.div_ceil(d) as u32
}

impl Reprojector {
    /// Compiles the pipelines on `ctx`'s device.
    ///
    /// # Errors
    /// [`GpuError::Device`] when a shader or pipeline fails to build on this device.
    pub fn new(ctx: &GpuContext, options: &ReprojectorOptions) -> Result<Reprojector> {
        ctx.loss.check(&ctx.device)?;
        let r = Self::with_device(&ctx.device, &ctx.queue, options).map(|r| Reprojector {
            loss: ctx.loss.clone(),
            ..r
        });
        ctx.loss.explain(&ctx.device, r)
    }

    /// Compiles the pipelines on a caller's device. The 64-bit splat is used when the device was
    /// created with `SHADER_INT64 | SHADER_INT64_ATOMIC_MIN_MAX` and the options do not force the
    /// 32-bit one. The device's loss is the caller's to watch (its lost callback is left alone):
    /// its errors are [`GpuError::Device`], never [`GpuError::Lost`].
    ///
    /// # Errors
    /// [`GpuError::Device`] when a shader or pipeline fails to build on this device.
    pub fn with_device(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        options: &ReprojectorOptions,
    ) -> Result<Reprojector> {
        let atomics = if !options.force_32bit_atomics
            && device.features().contains(int64_atomic_features())
        {
            Atomics::Int64
        } else {
            Atomics::Int32
        };
        scoped(device, "building the reprojection pipelines", || {
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("reproject"),
                entries: &bind_group_layout_entries(),
            });
            let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("reproject"),
                bind_group_layouts: &[&layout],
                push_constant_ranges: &[],
            });
            let module = |m: Module| {
                device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(m.file().0),
                    source: wgpu::ShaderSource::Wgsl(Cow::Owned(m.source())),
                })
            };
            let pipeline = |module: &wgpu::ShaderModule, entry: &str| {
                device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(entry),
                    layout: Some(&pl),
                    module,
                    entry_point: Some(entry),
                    compilation_options: wgpu::PipelineCompilationOptions::default(),
                    cache: None,
                })
            };
            let splat = match atomics {
                Atomics::Int64 => {
                    SplatPipelines::Int64(pipeline(&module(Module::Splat64), "splat_main"))
                }
                Atomics::Int32 => {
                    let m = module(Module::Splat32);
                    SplatPipelines::Int32 {
                        depth: pipeline(&m, "depth_pass"),
                        index: pipeline(&m, "index_pass"),
                    }
                }
            };
            let resolve_module = module(Module::Resolve);
            let aux_grid = pipeline(&resolve_module, "aux_grid");
            let resolve = pipeline(&resolve_module, "resolve");
            let ub = |label: &str, size: usize| {
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: size as u64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                })
            };
            Ok(Reprojector {
                device: device.clone(),
                queue: queue.clone(),
                atomics,
                layout,
                splat,
                aux_grid,
                resolve,
                frame_ub: ub("frame", std::mem::size_of::<FrameU>()),
                current: None,
                spare: None,
                outputs: (0..MAX_OUTPUTS).map(|_| None).collect(),
                generation: 0,
                loss: DeviceLoss::default(),
            })
        })
    }

    /// Which splat variant runs.
    pub fn atomics(&self) -> Atomics {
        self.atomics
    }

    /// Why its device was lost (polled now, without waiting), or `None`: after a loss every
    /// call fails with [`GpuError::Lost`]. Always `None` for a device of the caller's
    /// ([`Reprojector::with_device`]).
    pub fn lost(&self) -> Option<&str> {
        let _ = self.loss.check(&self.device);
        self.loss.reason()
    }

    /// Uploads the server frames of a pair and makes it current: `older` is `F_t` (with its
    /// forward motion and shadows), `newer` is `F_{t+1}` (with its backward motion and shadows), as
    /// [`reproj_core::reproject()`] takes them. `older` may be `None` (extrapolation only). The
    /// previous pair is dropped first (its device memory freed, unless an [`UploadedPair`] handle
    /// keeps it) and its per-frame buffers are reused when the new pair fits in them.
    ///
    /// # Errors
    /// As [`Uploader::upload`].
    pub fn load(&mut self, older: Option<&FrameView>, newer: &FrameView) -> Result<()> {
        if let Some(c) = self.current.take() {
            self.spare = Some(c.scratch);
        }
        let pair = self.uploader().upload(older, newer)?;
        self.install(Arc::new(pair)).map(drop)
    }

    /// What uploads pairs to this reprojector's device from another thread.
    pub fn uploader(&self) -> Uploader {
        Uploader {
            device: self.device.clone(),
            queue: self.queue.clone(),
            loss: self.loss.clone(),
        }
    }

    /// Makes an uploaded pair current: the following [`Reprojector::render`] calls read it. Nothing
    /// is copied; the per-frame buffers are reused when the pair fits in them (else allocated, the
    /// first time and when a pair is larger). Returns the pair that was current, so that the
    /// caller can drop it where freeing its device memory costs no frame (a receiving thread).
    ///
    /// # Errors
    /// [`GpuError::Device`] when the per-frame buffers cannot be allocated; [`GpuError::Lost`]
    /// once the device is lost. A pair uploaded to another device fails at the next render, as
    /// [`GpuError::Device`].
    pub fn install(&mut self, pair: Arc<UploadedPair>) -> Result<Option<Arc<UploadedPair>>> {
        self.loss.check(&self.device)?;
        let r = self.install_on_device(pair);
        self.loss.explain(&self.device, r)
    }

    fn install_on_device(&mut self, pair: Arc<UploadedPair>) -> Result<Option<Arc<UploadedPair>>> {
        let need = scratch_bytes(pair.points, pair.cells);
        let (old, previous) = match self.current.take() {
            Some(c) => (Some(c.scratch), Some(c.pair)),
            None => (self.spare.take(), None),
        };
        let scratch = match old {
            Some(s)
                if s.flow.size() >= need[0]
                    && s.splat.size() >= need[1]
                    && s.cells.size() >= need[2] =>
            {
                s
            }
            old => {
                // Free the smaller buffers before allocating the larger ones.
                drop(old);
                let device = self.device.clone();
                scoped(&device, "allocating the per-frame buffers", || {
                    let buf = |label: &str, size: u64| {
                        device.create_buffer(&wgpu::BufferDescriptor {
                            label: Some(label),
                            size,
                            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                            mapped_at_creation: false,
                        })
                    };
                    Ok(Scratch {
                        flow: buf("flow", need[0]),
                        splat: buf("splat", need[1]),
                        cells: buf("aux cells", need[2]),
                    })
                })?
            }
        };
        self.generation += 1;
        self.current = Some(Current {
            pair,
            scratch,
            generation: self.generation,
        });
        Ok(previous)
    }

    /// Drops the loaded pair and every output slot (device memory is freed).
    pub fn unload(&mut self) {
        self.current = None;
        self.spare = None;
        self.outputs.iter_mut().for_each(|o| *o = None);
    }

    /// Synthesises one client frame with `method` into output slot `slot` (`0..MAX_OUTPUTS`, e.g.
    /// one per eye), starting from `previous`. With `out` (`H·W·3` RGB8) the image is downloaded
    /// into it, and with `diag` the per-pixel diagnostics; without either the frame stays on the
    /// device ([`Reprojector::output_buffer`]).
    ///
    /// Only the client transfers and `α` go up per call (a uniform of under 1 KiB).
    ///
    /// # Errors
    /// The CPU path's input errors for the method, `α`, options and camera (same messages);
    /// [`GpuError::Unsupported`] for `timewarp` and `backward_bidir`; [`GpuError::Order`] when no
    /// pair is loaded; [`GpuError::TooLarge`] for a client image larger than the device's
    /// buffers can bind; [`GpuError::Device`] for device errors; [`GpuError::Lost`] once the
    /// device is lost (a reprojector made by [`Reprojector::new`]).
    pub fn render(
        &mut self,
        slot: usize,
        method: Method,
        request: &Request,
        params: &Params,
        previous: Previous<'_>,
        out: Option<&mut [u8]>,
        diag: Option<&mut Diagnostics>,
    ) -> Result<()> {
        self.loss.check(&self.device)?;
        let r = self.render_on_device(slot, method, request, params, previous, out, diag);
        self.loss.explain(&self.device, r)
    }

    fn render_on_device(
        &mut self,
        slot: usize,
        method: Method,
        request: &Request,
        params: &Params,
        previous: Previous<'_>,
        out: Option<&mut [u8]>,
        diag: Option<&mut Diagnostics>,
    ) -> Result<()> {
        params.validate()?;
        let client = &request.client;
        client.projector("client camera")?;
        let (cw, ch) = (client.width, client.height);
        let n = cw * ch;
        let size_err = |what: &str, expected: usize, actual: usize, detail: String| {
            GpuError::Input(ReprojError::BufferSize {
                what: what.into(),
                expected,
                actual,
                detail,
            })
        };
        // The output and the previous client frame: client-sized RGB8 images.
        let check_rgb = |what: &str, len: usize| {
            if len == n * 3 {
                Ok(())
            } else {
                Err(size_err(what, n * 3, len, format!("{ch}x{cw}x3")))
            }
        };
        if let Some(o) = out.as_deref() {
            check_rgb("output image", o.len())?;
        }
        if let Previous::Image(p) = previous {
            check_rgb("previous client frame", p.len())?;
        }
        if let Some(d) = diag.as_deref() {
            // Named as the CPU path names them (reproj_core's Output::check).
            for (what, len) in [("source", d.source.len()), ("error", d.error.len())] {
                if len != n {
                    let what = format!("diagnostics.{what}");
                    return Err(size_err(&what, n, len, format!("{ch}x{cw}")));
                }
            }
        }
        if slot >= MAX_OUTPUTS {
            return Err(GpuError::Unsupported(format!(
                "output slot {slot}: expected 0 to {}",
                MAX_OUTPUTS - 1
            )));
        }
        let Some(current) = self.current.as_ref() else {
            return Err(GpuError::Order(
                "no server frames on the device: call load() or install() before render()".into(),
            ));
        };
        let (pair, generation) = (current.pair.clone(), current.generation);
        let has_older = pair.has_older();
        let (mode, bidirectional) = plan(method, has_older, request.alpha, params)?;
        let frame = self.frame_uniform(&pair, mode, bidirectional, request, params);
        let n_aux = frame.n_aux as usize;
        let active: Vec<usize> = (0..=n_aux)
            .flat_map(|c| {
                if bidirectional {
                    vec![2 * c, 2 * c + 1]
                } else {
                    vec![2 * c + 1]
                }
            })
            .collect();
        let (mut mw, mut mh) = (0, 0);
        for &s in &active {
            if let Some(sl) = pair.slots[s] {
                mw = mw.max(sl.width);
                mh = mh.max(sl.height);
            }
        }
        let (mut aw, mut ah) = (0, 0);
        for c in 1..=n_aux {
            if let Some(sl) = pair.slots[2 * c + 1] {
                aw = aw.max(sl.width);
                ah = ah.max(sl.height);
            }
        }
        let device = self.device.clone();
        let want_image = out.is_some();
        let want_diag = diag.is_some();
        scoped(&device, "rendering a client frame", || {
            self.ensure_output(slot, cw, ch, generation)?;
            let Some(o) = self.outputs[slot].as_ref() else {
                return Err(GpuError::State("output slot missing".into()));
            };
            let Some(current) = self.current.as_ref() else {
                return Err(GpuError::State("pair buffers missing".into()));
            };
            let Some((_, bind_group)) = o.bind_group.as_ref() else {
                return Err(GpuError::State("bind group missing".into()));
            };
            let q = &self.queue;
            q.write_buffer(&self.frame_ub, 0, bytemuck::bytes_of(&frame));
            let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("client frame"),
            });
            match previous {
                Previous::Keep => {}
                Previous::Black => enc.clear_buffer(&o.rgb, 0, None),
                Previous::Image(img) => {
                    let packed: Vec<u32> = img.chunks_exact(3).map(pack_rgb).collect();
                    q.write_buffer(&o.rgb, 0, bytemuck::cast_slice(&packed));
                }
            }
            enc.clear_buffer(&current.scratch.splat, 0, None);
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("reproject"),
                    timestamp_writes: None,
                });
                pass.set_bind_group(0, bind_group, &[]);
                let (gx, gy, layers) = (
                    div_ceil_u32(mw, TILE),
                    div_ceil_u32(mh, TILE),
                    active.len() as u32,
                );
                match &self.splat {
                    SplatPipelines::Int64(p) => {
                        pass.set_pipeline(p);
                        pass.dispatch_workgroups(gx, gy, layers);
                    }
                    SplatPipelines::Int32 { depth, index } => {
                        pass.set_pipeline(depth);
                        pass.dispatch_workgroups(gx, gy, layers);
                        pass.set_pipeline(index);
                        pass.dispatch_workgroups(gx, gy, layers);
                    }
                }
                if n_aux > 0 {
                    pass.set_pipeline(&self.aux_grid);
                    pass.dispatch_workgroups(
                        div_ceil_u32(aw, TILE),
                        div_ceil_u32(ah, TILE),
                        n_aux as u32,
                    );
                }
                pass.set_pipeline(&self.resolve);
                pass.dispatch_workgroups(div_ceil_u32(cw, TILE), div_ceil_u32(ch, TILE), 1);
            }
            if want_image {
                enc.copy_buffer_to_buffer(&o.rgb, 0, &o.staging_rgb, 0, o.rgb.size());
            }
            if want_diag {
                enc.copy_buffer_to_buffer(&o.diag, 0, &o.staging_diag, 0, o.diag.size());
            }
            q.submit([enc.finish()]);
            Ok(())
        })?;
        let Some(o) = self.outputs[slot].as_ref() else {
            return Err(GpuError::State("output slot missing".into()));
        };
        if let Some(out) = out {
            let words = read_buffer(&self.device, &o.staging_rgb)?;
            for (px, w) in out.chunks_exact_mut(3).zip(words.iter()) {
                px.copy_from_slice(&w.to_le_bytes()[..3]);
            }
        }
        if let Some(d) = diag {
            let words = read_buffer(&self.device, &o.staging_diag)?;
            for (k, pair) in words.chunks_exact(2).enumerate().take(n) {
                d.source[k] = pair[0] as u8;
                d.error[k] = f32::from_bits(pair[1]);
            }
        }
        Ok(())
    }

    /// [`reproj_core::reproject()`]'s signature on the GPU: `out` holds the previous client frame
    /// on entry and the new one on return (output slot 0).
    ///
    /// # Errors
    /// As [`Reprojector::render`].
    pub fn reproject(
        &mut self,
        method: Method,
        request: &Request,
        params: &Params,
        out: &mut [u8],
        diag: Option<&mut Diagnostics>,
    ) -> Result<()> {
        let prev = out.to_vec();
        self.render(
            0,
            method,
            request,
            params,
            Previous::Image(&prev),
            Some(out),
            diag,
        )
    }

    /// The device buffer of output slot `slot` (`u32` per pixel, `R | G << 8 | B << 16`, row-major,
    /// row 0 at the top) with its size, for a caller that presents frames without downloading
    /// them; `None` before the first [`Reprojector::render`] into it.
    pub fn output_buffer(&self, slot: usize) -> Option<(&wgpu::Buffer, usize, usize)> {
        self.outputs
            .get(slot)?
            .as_ref()
            .map(|o| (&o.rgb, o.width, o.height))
    }

    fn frame_uniform(
        &self,
        pair: &UploadedPair,
        mode: Mode,
        bidirectional: bool,
        request: &Request,
        params: &Params,
    ) -> FrameU {
        let alpha = request.alpha;
        let (cw, ch) = (request.client.width, request.client.height);
        let eps_scale = REFERENCE_SHORT_SIDE / cw.min(ch) as f32;
        let client_vp = request.client.view_proj();
        let n_aux = if params.use_aux { pair.n_aux } else { 0 };
        let mut f = FrameU::zeroed();
        f.client_w = cw as u32;
        f.client_h = ch as u32;
        f.alpha = alpha;
        f.mode = match mode {
            Mode::Ours => 0,
            Mode::ForwardSplat => 1,
        };
        f.bidirectional = u32::from(bidirectional);
        f.n_aux = n_aux as u32;
        f.iterations = if mode == Mode::Ours {
            params.fpi_iterations as u32
        } else {
            0
        };
        f.window = params.window as u32;
        f.subframes = params.shadow_subframes as u32;
        f.shadows = u32::from(mode == Mode::Ours && params.use_shadows);
        f.blend = u32::from(bidirectional && mode == Mode::Ours && params.blend);
        f.vis_other = u32::from(bidirectional);
        f.eps_e = params.eps_e * eps_scale;
        f.eps_e_aux = params.eps_e * eps_scale * params.aux_threshold_scale;
        f.eps_z = params.eps_z;
        f.eps_z_aux = params.eps_z_aux();
        f.eps_o = params.eps_o;
        for (s, slot) in pair.slots.iter().enumerate() {
            if let Some(sl) = slot {
                f.sources[s] = FrameSourceU {
                    to_client: TransferU::from(&NdcTransfer::new(&sl.inv, &client_vp)),
                    w: if s % 2 == 0 { alpha } else { 1.0 - alpha },
                    _pad: [0.0; 3],
                };
            }
        }
        f
    }

    fn ensure_output(&mut self, slot: usize, w: usize, h: usize, generation: u64) -> Result<()> {
        let fits = self.outputs[slot]
            .as_ref()
            .is_some_and(|o| o.width == w && o.height == h);
        if !fits {
            let n = (w * h) as u64;
            // Before the device is asked: wgpu's own refusal came back as a validation error
            // of a bind group, not as the caller's input.
            let need = [("output", n * OUT_BYTES), ("diagnostics", n * DIAG_BYTES)];
            let what = format!("the {w}x{h} client image");
            check_bindings(
                &self.device.limits(),
                &what,
                &need,
                "a smaller client camera",
            )?;
            let buf = |label: &str, size: u64, usage: wgpu::BufferUsages| {
                self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size,
                    usage,
                    mapped_at_creation: false,
                })
            };
            let st = wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST;
            let rd = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
            // New buffers are zero-initialised by wgpu: a new slot starts black.
            self.outputs[slot] = Some(Output {
                width: w,
                height: h,
                rgb: buf("output", n * OUT_BYTES, st),
                diag: buf("diagnostics", n * DIAG_BYTES, st),
                staging_rgb: buf("output staging", n * OUT_BYTES, rd),
                staging_diag: buf("diagnostics staging", n * DIAG_BYTES, rd),
                bind_group: None,
            });
        }
        let Some(current) = self.current.as_ref() else {
            return Err(GpuError::State("no pair".into()));
        };
        let Some(o) = self.outputs[slot].as_mut() else {
            return Err(GpuError::State("output slot missing".into()));
        };
        if o.bind_group.as_ref().is_none_or(|(g, _)| *g != generation) {
            let bg = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("reproject"),
                layout: &self.layout,
                entries: &[
                    entry(0, &self.frame_ub),
                    entry(1, &current.pair.sources),
                    entry(2, &current.pair.texels),
                    entry(3, &current.scratch.flow),
                    entry(4, &current.scratch.splat),
                    entry(5, &current.scratch.cells),
                    entry(6, &o.rgb),
                    entry(7, &o.diag),
                ],
            });
            o.bind_group = Some((generation, bg));
        }
        Ok(())
    }
}

impl Uploader {
    /// Uploads the server frames of a pair as [`Reprojector::load`] takes them, without making it
    /// current ([`Reprojector::install`] does, between two frames). Callable from another thread
    /// while a reprojector of the same device renders: the texels are packed straight into buffers
    /// mapped at creation, outside any error scope, so a frame waits at most for the creation of
    /// the two buffers.
    ///
    /// # Errors
    /// The CPU path's input errors ([`GpuError::Input`]: buffer sizes, camera mismatch, singular
    /// matrices); [`GpuError::Unsupported`] for more than [`MAX_CAMERAS`] cameras per frame;
    /// [`GpuError::TooLarge`] when the buffers exceed the device's limits, [`GpuError::Device`]
    /// when its memory; [`GpuError::Lost`] once the device is lost.
    pub fn upload(&self, older: Option<&FrameView>, newer: &FrameView) -> Result<UploadedPair> {
        self.loss.check(&self.device)?;
        let r = self.upload_to_device(older, newer);
        self.loss.explain(&self.device, r)
    }

    fn upload_to_device(
        &self,
        older: Option<&FrameView>,
        newer: &FrameView,
    ) -> Result<UploadedPair> {
        FrameView::validate_pair(older, newer)?;
        let n_cams = 1 + newer.aux.len();
        if n_cams > MAX_CAMERAS {
            return Err(GpuError::Unsupported(format!(
                "the wgpu backend takes at most {} auxiliary cameras per frame, got {}",
                MAX_CAMERAS - 1,
                newer.aux.len()
            )));
        }
        // Slot views and projectors (a singular matrix is reported before any upload).
        let mut views: [Option<CameraView>; MAX_SLOTS] = [None; MAX_SLOTS];
        let mut slots: [Option<Slot>; MAX_SLOTS] = [None; MAX_SLOTS];
        let mut vps: [Option<Mat4>; MAX_SLOTS] = [None; MAX_SLOTS];
        for cam in 0..n_cams {
            for (role, frame) in [(0, older), (1, Some(newer))] {
                let Some(f) = frame else { continue };
                let which = if role == 0 { "older" } else { "newer" };
                let (view, name) = if cam == 0 {
                    (f.main, format!("{which}.main"))
                } else {
                    (f.aux[cam - 1], format!("{which}.aux[{}]", cam - 1))
                };
                view.camera.projector(&name)?;
                let vp = view.camera.view_proj();
                let inv = vp
                    .inverse()
                    .ok_or(ReprojError::SingularMatrix { what: name })?;
                let s = 2 * cam + role;
                views[s] = Some(view);
                vps[s] = Some(vp);
                slots[s] = Some(Slot {
                    width: view.camera.width,
                    height: view.camera.height,
                    inv,
                });
            }
        }
        // Static uniforms and the concatenated texels.
        let mut su = [SourceU::zeroed(); MAX_SLOTS];
        let mut total = 0usize;
        let mut cells = 0usize;
        for s in 0..MAX_SLOTS {
            let (Some(slot), Some(vp)) = (slots[s], vps[s]) else {
                continue;
            };
            let u = &mut su[s];
            u.offset = total as u32;
            u.width = slot.width as u32;
            u.height = slot.height as u32;
            u.present = 1;
            total += slot.width * slot.height;
            if s >= 2 && s % 2 == 1 {
                u.cell_offset = cells as u32;
                cells += slot.width * slot.height;
            }
            let other = s ^ 1;
            if let (Some(o), Some(ovp)) = (slots[other], vps[other]) {
                u.to_other = TransferU::from(&NdcTransfer::new(&slot.inv, &ovp));
                u.from_other = TransferU::from(&NdcTransfer::new(&o.inv, &vp));
            }
            let role = s % 2;
            if let Some(mvp) = vps[role] {
                u.to_main_same = TransferU::from(&NdcTransfer::new(&slot.inv, &mvp));
            }
            if let Some(mvp) = vps[1 - role] {
                u.to_main_other = TransferU::from(&NdcTransfer::new(&slot.inv, &mvp));
            }
        }
        let limits = self.device.limits();
        // The pair's texels, and the per-frame buffers [`Reprojector::install`] sizes for it.
        let [flow, splat, aux_cells] = scratch_bytes(total, cells);
        let need = [
            (
                "texels",
                total as u64 * std::mem::size_of::<TexelU>() as u64,
            ),
            ("flow", flow),
            ("splat", splat),
            ("auxiliary cells", aux_cells),
        ];
        check_bindings(&limits, "this pair", &need, "smaller frames")?;
        let device = &self.device;
        let (texels, sources) = scoped(device, "uploading the server frames", || {
            let buf = |label: &str, size: u64, usage: wgpu::BufferUsages| {
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size,
                    usage,
                    mapped_at_creation: true,
                })
            };
            Ok((
                buf("texels", need[0].1, wgpu::BufferUsages::STORAGE),
                buf(
                    "sources",
                    std::mem::size_of_val(&su) as u64,
                    wgpu::BufferUsages::UNIFORM,
                ),
            ))
        })?;
        // Buffers made on a device lost since the check above are invalid, and mapping an invalid
        // buffer panics (wgpu reports no error for them: WebGPU's rule for a lost device). A
        // destroyed device is known to be lost only once its queue is empty: this waits for the
        // work in flight (the display's frame; this runs on the uploading thread).
        self.loss.check_drained(device)?;
        {
            let mut mapped = texels.slice(..).get_mapped_range_mut();
            let mut rest: &mut [TexelU] = bytemuck::cast_slice_mut(&mut mapped);
            for view in views.iter().flatten() {
                let (this, next) = rest.split_at_mut(view.camera.width * view.camera.height);
                pack_texels(view, this);
                rest = next;
            }
            sources
                .slice(..)
                .get_mapped_range_mut()
                .copy_from_slice(bytemuck::cast_slice(&su));
        }
        scoped(device, "uploading the server frames", || {
            texels.unmap();
            sources.unmap();
            // Nothing to run: the submit hands the unmapped buffers' contents to the device now,
            // on this thread, rather than with the next frame's submit on the display's.
            self.queue.submit([]);
            Ok(())
        })?;
        Ok(UploadedPair {
            slots,
            n_aux: n_cams - 1,
            points: total,
            cells,
            texels,
            sources,
        })
    }
}

/// Refuses buffers that `limits` cannot bind as storage (or create at all): `need` names each
/// buffer of `what` and its bytes; `smaller` says what to make smaller instead.
fn check_bindings(
    limits: &wgpu::Limits,
    what: &str,
    need: &[(&str, u64)],
    smaller: &str,
) -> Result<()> {
    let max = limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size.min(u64::from(u32::MAX)) as u32) as u64;
    for &(name, bytes) in need {
        if bytes > max {
            return Err(GpuError::TooLarge(format!(
                "the {name} buffer of {what} needs {bytes} bytes, above this device's storage \
                 binding limit of {max} bytes; use {smaller} or backend 'cpu'"
            )));
        }
    }
    Ok(())
}

/// Bytes of the per-frame buffers (flow, splat, auxiliary cells) of a pair with `points` source
/// points and `cells` auxiliary cells: what [`Uploader::upload`] checks against the device's
/// limits and [`Reprojector::install`] allocates.
fn scratch_bytes(points: usize, cells: usize) -> [u64; 3] {
    [
        points as u64 * FLOW_BYTES,
        points as u64 * SPLAT_BYTES,
        cells.max(1) as u64 * AUX_CELL_BYTES,
    ]
}

/// Writes the texels of one source image into `out` (one per pixel): colour, depth, motion,
/// shadows; zeros where absent, which the kernels treat exactly as "no motion" and "no dynamic
/// shadow".
fn pack_texels(view: &CameraView, out: &mut [TexelU]) {
    for (k, t) in out.iter_mut().enumerate() {
        let (bits, s_min, s_max) = match &view.shadow {
            Some(s) => (
                s.bits[k],
                pack_rgb(&s.s_min[3 * k..3 * k + 3]),
                pack_rgb(&s.s_max[3 * k..3 * k + 3]),
            ),
            None => (0, 0, 0),
        };
        *t = TexelU {
            color: pack_rgb(&view.color[3 * k..3 * k + 3]),
            depth: view.depth[k],
            motion: view.motion_at(k),
            bits,
            s_min,
            s_max,
        };
    }
}

/// Maps a staging buffer, copies its words out and unmaps it.
fn read_buffer(device: &wgpu::Device, buffer: &wgpu::Buffer) -> Result<Vec<u32>> {
    let (tx, rx) = mpsc::channel();
    buffer.slice(..).map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::Wait)
        .map_err(|e| GpuError::Device(format!("waiting for the device: {e}")))?;
    rx.recv()
        .map_err(|_| GpuError::Device("the map callback never ran".into()))?
        .map_err(|e| GpuError::Device(format!("reading back a result: {e}")))?;
    let words = {
        let view = buffer.slice(..).get_mapped_range();
        bytemuck::cast_slice::<u8, u32>(&view).to_vec()
    };
    buffer.unmap();
    Ok(words)
}

/// Which pipeline `method` runs and whether bidirectionally, with the checks and messages of
/// [`reproj_core::reproject()`] (`method.rs`) for `α` and missing frames.
fn plan(method: Method, has_older: bool, alpha: f32, params: &Params) -> Result<(Mode, bool)> {
    let range_err = |range: &str| {
        GpuError::Input(ReprojError::AlphaRange {
            alpha,
            method: method.name().into(),
            range: range.into(),
        })
    };
    if !(alpha.is_finite() && (0.0..=MAX_ALPHA).contains(&alpha)) {
        return Err(range_err("[0, 3]"));
    }
    // As reproj-core `run`: the older frame only takes part while interpolating.
    let interpolating = has_older && alpha < 1.0;
    match method {
        Method::Ours => {
            if !has_older && alpha < 1.0 {
                return Err(ReprojError::MissingFrame(
                    "method 'ours' interpolates for alpha < 1 and needs the older frame; pass it, or use alpha >= 1 to extrapolate from the newer frame".into(),
                )
                .into());
            }
            Ok((Mode::Ours, interpolating))
        }
        Method::OursExtrapolate => {
            if alpha < 1.0 {
                return Err(range_err(
                    "[1, 3] (extrapolation from the newest frame, given as `newer`)",
                ));
            }
            Ok((Mode::Ours, false))
        }
        Method::ForwardSplat => {
            if params.splat_bidirectional {
                if !has_older && alpha < 1.0 {
                    return Err(ReprojError::MissingFrame(
                        "bidirectional forward_splat with alpha < 1 needs the older frame".into(),
                    )
                    .into());
                }
                Ok((Mode::ForwardSplat, interpolating))
            } else {
                if alpha < 1.0 {
                    return Err(range_err(
                        "[1, 3] (unidirectional splatting from the newest frame, given as `newer`)",
                    ));
                }
                Ok((Mode::ForwardSplat, false))
            }
        }
        Method::Timewarp | Method::BackwardBidir => Err(GpuError::Unsupported(format!(
            "method '{}' has no wgpu kernel (the GPU path runs ours, ours_extrapolate and \
             forward_splat); use backend 'cpu' for it",
            method.name()
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_mirrors_the_cpu_checks() {
        let p = Params::default();
        assert_eq!(
            plan(Method::Ours, true, 0.5, &p).unwrap(),
            (Mode::Ours, true)
        );
        assert_eq!(
            plan(Method::Ours, true, 1.5, &p).unwrap(),
            (Mode::Ours, false)
        );
        assert!(matches!(
            plan(Method::Ours, false, 0.5, &p),
            Err(GpuError::Input(ReprojError::MissingFrame(_)))
        ));
        assert!(matches!(
            plan(Method::OursExtrapolate, true, 0.5, &p),
            Err(GpuError::Input(ReprojError::AlphaRange { .. }))
        ));
        assert!(matches!(
            plan(Method::Ours, true, 3.5, &p),
            Err(GpuError::Input(ReprojError::AlphaRange { .. }))
        ));
        let bi = Params {
            splat_bidirectional: true,
            ..p
        };
        assert_eq!(
            plan(Method::ForwardSplat, true, 0.25, &bi).unwrap(),
            (Mode::ForwardSplat, true)
        );
        assert!(matches!(
            plan(Method::Timewarp, true, 0.5, &p),
            Err(GpuError::Unsupported(_))
        ));
    }

    /// reproj-core's routing (`method.rs`, `route`) at the edges of α, written out by hand: the
    /// older frame takes part exactly when α < 1 (not at α = 1), α = 3 is allowed and NaN is
    /// not, the missing-frame errors only below α = 1, the unidirectional methods refuse α < 1
    /// with their own ranges, and neither CPU-only method runs.
    #[test]
    fn plan_at_the_edges_of_alpha() {
        #[derive(Debug, PartialEq)]
        enum Want {
            Run(Mode, bool),
            Range(&'static str),
            Missing,
            Unsupported,
        }
        use Want::{Missing, Range, Run, Unsupported};
        let uni = Params::default();
        let bi = Params {
            splat_bidirectional: true,
            ..uni
        };
        let below = 1.0 - f32::EPSILON;
        let ours_range = "[1, 3] (extrapolation from the newest frame, given as `newer`)";
        let splat_range =
            "[1, 3] (unidirectional splatting from the newest frame, given as `newer`)";
        let table = [
            (Method::Ours, uni, true, 0.0, Run(Mode::Ours, true)),
            (Method::Ours, uni, true, below, Run(Mode::Ours, true)),
            (Method::Ours, uni, true, 1.0, Run(Mode::Ours, false)),
            (Method::Ours, uni, true, 3.0, Run(Mode::Ours, false)),
            (
                Method::Ours,
                uni,
                true,
                3.0 + 4.0 * f32::EPSILON,
                Range("[0, 3]"),
            ),
            (Method::Ours, uni, true, -0.25, Range("[0, 3]")),
            (Method::Ours, uni, true, f32::NAN, Range("[0, 3]")),
            (Method::Ours, uni, true, f32::INFINITY, Range("[0, 3]")),
            (Method::Ours, uni, false, below, Missing),
            (Method::Ours, uni, false, 1.0, Run(Mode::Ours, false)),
            (Method::OursExtrapolate, uni, true, below, Range(ours_range)),
            (
                Method::OursExtrapolate,
                uni,
                true,
                1.0,
                Run(Mode::Ours, false),
            ),
            (
                Method::OursExtrapolate,
                uni,
                false,
                3.0,
                Run(Mode::Ours, false),
            ),
            (Method::ForwardSplat, uni, true, below, Range(splat_range)),
            (
                Method::ForwardSplat,
                uni,
                true,
                1.0,
                Run(Mode::ForwardSplat, false),
            ),
            (
                Method::ForwardSplat,
                bi,
                true,
                below,
                Run(Mode::ForwardSplat, true),
            ),
            (
                Method::ForwardSplat,
                bi,
                true,
                1.0,
                Run(Mode::ForwardSplat, false),
            ),
            (Method::ForwardSplat, bi, false, below, Missing),
            (
                Method::ForwardSplat,
                bi,
                false,
                1.5,
                Run(Mode::ForwardSplat, false),
            ),
            (Method::Timewarp, uni, true, 1.5, Unsupported),
            (Method::BackwardBidir, uni, true, 0.5, Unsupported),
        ];
        for (method, params, has_older, alpha, want) in table {
            let got = match plan(method, has_older, alpha, &params) {
                Ok((mode, bidirectional)) => Run(mode, bidirectional),
                Err(GpuError::Input(ReprojError::AlphaRange {
                    alpha: a,
                    method: m,
                    range,
                })) => {
                    assert_eq!((a.to_bits(), m.as_str()), (alpha.to_bits(), method.name()));
                    match range.as_str() {
                        "[0, 3]" => Range("[0, 3]"),
                        r if r == ours_range => Range(ours_range),
                        r if r == splat_range => Range(splat_range),
                        r => panic!("{method:?} at {alpha}: range {r:?}"),
                    }
                }
                Err(GpuError::Input(ReprojError::MissingFrame(_))) => Missing,
                Err(GpuError::Unsupported(_)) => Unsupported,
                Err(e) => panic!("{method:?} at {alpha}: {e:?}"),
            };
            assert_eq!(
                got, want,
                "{method:?}, bidirectional splat {}, older {has_older}, alpha {alpha}",
                params.splat_bidirectional
            );
        }
    }
}
