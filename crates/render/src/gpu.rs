//! The wgpu compute rasterizer (Schütz et al. 2021): point columns live in
//! storage buffers, each shader invocation transforms a few points and does an
//! `atomicMin` of `depth << 32 | colour` per covered pixel into a 64-bit
//! framebuffer (`SHADER_INT64_ATOMIC_MIN_MAX`; guarded by a plain `atomicLoad`
//! depth pre-test where all 64-bit atomic ops exist), or of
//! `log-depth16 << 16 | bgr565` into a 32-bit one where 64-bit atomics are
//! missing (GL, older GPUs). A resolve pass writes RGBA8 (and linear depth for
//! eye-dome lighting), resets the framebuffer and the frame is read back. Runs
//! headless (pollster), also on software adapters such as lavapipe/llvmpipe.
//!
//! Point buffers are split into chunks no larger than the adapter's
//! storage-buffer binding limit (128 MiB on the software backends), one dispatch
//! each, and cached between frames keyed by column address and length (plus a
//! sampled content fingerprint); batches not drawn recently are dropped LRU
//! beyond a byte budget.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, Once};
use std::time::Instant;

use bytemuck::{Pod, Zeroable};

use super::{
    Camera, Frame, FrameStats, PointBatch, Rasterizer, RenderError, RenderOptions, edl, pick,
    total_points,
};

const RASTERIZE64: &str = include_str!("../shaders/rasterize.wgsl");
const RASTERIZE_SUBGROUP: &str = include_str!("../shaders/rasterize_subgroup.wgsl");
const RASTERIZE32: &str = include_str!("../shaders/rasterize_u32.wgsl");
/// Appended to the rasterizers and the id pass (WGSL has no includes): their
/// parameters, point bindings and transform.
const PROJECT: &str = include_str!("../shaders/project.wgsl");
const RESOLVE: &str = include_str!("../shaders/resolve.wgsl");
/// The id pass, with the framebuffer test for the 64- or 32-bit path.
const IDS: &str = include_str!("../shaders/ids.wgsl");
const IDS_MATCH64: &str = include_str!("../shaders/ids_match64.wgsl");
const IDS_MATCH32: &str = include_str!("../shaders/ids_match32.wgsl");

const WORKGROUP: u32 = 256;
const MAX_GROUPS_X: u32 = 65535;
/// Points per shader invocation: fewer, longer invocations measured ~1.5x
/// faster than one point each on lavapipe.
const DEFAULT_POINTS_PER_THREAD: u32 = 8;
/// Points per invocation on a software adapter, where the merge of same-pixel
/// runs pays off with longer runs (lavapipe: 8 → 96, 16 → 105, 32 → 106–110,
/// 64 → 100–103 M points/s).
const SOFTWARE_POINTS_PER_THREAD: u32 = 32;
/// Points per invocation with the subgroup reduction (NVIDIA H200, 500 M
/// Morton-ordered points at 1280×720, best frame: 4 → 6.0, 8 → 3.9, 16 → 3.5 ms;
/// bench/history/41).
const SUBGROUP_POINTS_PER_THREAD: u32 = 16;
/// Default [`GpuRasterizer::set_cache_budget`].
const DEFAULT_CACHE_BUDGET: u64 = 1 << 30;
/// Longest wait for the device before a frame fails (instead of hanging).
const GPU_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(60);

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct RasterParams {
    mvp: [f32; 16],
    width: u32,
    height: u32,
    point_size: u32,
    count: u32,
    hw: f32,
    hh: f32,
    off: f32,
    log2_near: f32,
    depth_scale: f32,
    /// The frame-wide id of this chunk's first point (the id pass only).
    id_base: u32,
    _pad: [u32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ResolveParams {
    quads: u32,
    background: u32,
    log2_near: f32,
    depth_scale: f32,
    _unused: u32,
    write_depth: u32,
    _pad: [u32; 2],
}

/// Workgroup counts (x, y) covering `n` invocations, and the invocations per row.
fn dispatch_shape(n: u32) -> (u32, u32, u32) {
    let groups = n.div_ceil(WORKGROUP).max(1);
    let gx = groups.min(MAX_GROUPS_X);
    let gy = groups.div_ceil(gx);
    (gx, gy, gx * WORKGROUP)
}

/// One uploaded slice of a batch: at most `chunk_points` points.
struct Chunk {
    count: u32,
    /// First point's index within its batch.
    start: u32,
    params: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    /// The same buffers bound for the id pass.
    ids_bind_group: wgpu::BindGroup,
    _buffers: [wgpu::Buffer; 4],
}

struct CacheEntry {
    fingerprint: u64,
    /// Bytes of point data held on the device.
    bytes: u64,
    chunks: Vec<Chunk>,
    last_used: u64,
}

/// Cache key: the four column slices (address, length).
type Key = [usize; 5];

fn batch_key(b: &PointBatch<'_>) -> Key {
    [
        b.x.as_ptr() as usize,
        b.y.as_ptr() as usize,
        b.z.as_ptr() as usize,
        b.color.as_ptr() as usize,
        b.len(),
    ]
}

/// A cheap content check guarding the address-keyed cache against a freed and
/// reused allocation: hashes up to 64 values from each column.
fn fingerprint(b: &PointBatch<'_>) -> u64 {
    let n = b.len();
    let mut h: u64 = 0xcbf2_9ce4_8422_2325 ^ n as u64;
    let mut mix = |v: u32| {
        h ^= v as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    };
    if n == 0 {
        return h;
    }
    let step = n.div_ceil(64).max(1);
    let mut i = 0;
    while i < n {
        mix(b.x[i].to_bits());
        mix(b.y[i].to_bits());
        mix(b.z[i].to_bits());
        mix(b.color[i]);
        i += step;
    }
    mix(b.x[n - 1].to_bits());
    mix(b.color[n - 1]);
    h
}

/// Framebuffer-sized resources for one frame size.
struct Targets {
    width: u32,
    height: u32,
    resolve_params: wgpu::Buffer,
    out: wgpu::Buffer,
    staging: wgpu::Buffer,
    raster_bg: wgpu::BindGroup,
    clear_bg: wgpu::BindGroup,
    resolve_bg: wgpu::BindGroup,
    fb: wgpu::Buffer,
    /// Made on the first frame that keeps ids.
    ids: Option<IdTargets>,
}

/// The per-pixel id buffer, its readback copy and its binding.
struct IdTargets {
    buf: wgpu::Buffer,
    staging: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

/// The wgpu compute rasterizer.
pub struct GpuRasterizer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    int64: bool,
    raster: wgpu::ComputePipeline,
    clear: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    ids_pipeline: wgpu::ComputePipeline,
    /// Whether frames fill `ids` ([`Rasterizer::keep_ids`]).
    keep_ids: bool,
    ids: Vec<u64>,
    chunk_points: usize,
    points_per_thread: u32,
    early_out: bool,
    /// 1-pixel points go through `main_subgroup`.
    subgroups: bool,
    max_binding: u64,
    targets: Option<Targets>,
    /// The framebuffer may hold stale values (new, or a frame failed midway):
    /// the next frame clears it first. Otherwise resolve leaves it cleared.
    fb_dirty: bool,
    cache: HashMap<Key, CacheEntry>,
    /// Bytes of point buffers kept for batches not drawn in the last frame.
    cache_budget: u64,
    frame: u64,
    errors: Arc<Mutex<Option<String>>>,
}

static QUIET_MESA: Once = Once::new();

/// Sets `NODEVICE_SELECT=1` (unless already set) so Mesa's Vulkan device-select
/// layer stays quiet on stderr. Called by [`GpuRasterizer::new`]; programs should
/// call it (or set the variable) at startup, before spawning threads.
pub(crate) fn quiet_mesa_layers() {
    QUIET_MESA.call_once(|| {
        if std::env::var_os("NODEVICE_SELECT").is_none() {
            // SAFETY: `set_var` is unsound only against environment reads that
            // bypass std's environment lock, i.e. C code calling getenv on
            // another thread at the same moment. The C code that reads this
            // variable is the Vulkan loader/Mesa, which only runs after this
            // `Once` completes (every instance creation goes through here first
            // and waits for it), so no Vulkan code can be running yet. Programs
            // with other C threads should call this at startup before spawning
            // them, or set NODEVICE_SELECT themselves, which skips the write.
            unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
        }
    });
}

/// Scores at or above this are hardware adapters.
const HARDWARE_SCORE: u32 = 20;

/// Preference of an adapter: device type first (hardware > software), then
/// Vulkan over GL, then 64-bit atomics. `None` when it cannot run compute shaders.
fn adapter_score(a: &wgpu::Adapter) -> Option<u32> {
    let info = a.get_info();
    let caps = a.get_downlevel_capabilities();
    if !caps.flags.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS) {
        return None;
    }
    let ty = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 40,
        wgpu::DeviceType::IntegratedGpu => 30,
        wgpu::DeviceType::VirtualGpu => 20,
        wgpu::DeviceType::Cpu => 10,
        wgpu::DeviceType::Other => 5,
    };
    let backend = if info.backend == wgpu::Backend::Vulkan {
        2
    } else {
        0
    };
    let atomics = if a
        .features()
        .contains(wgpu::Features::SHADER_INT64 | wgpu::Features::SHADER_INT64_ATOMIC_MIN_MAX)
    {
        1
    } else {
        0
    };
    Some(ty + backend + atomics)
}

/// Construction options for [`GpuRasterizer::with_options`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GpuOptions {
    /// Use the 32-bit fallback (16-bit depth, BGR565) even where 64-bit atomics exist.
    pub force_32bit_atomics: bool,
    /// Skip the plain `atomicLoad` depth pre-test that otherwise guards each
    /// `atomicMin` where `SHADER_INT64_ATOMIC_ALL_OPS` exists (it measured
    /// 0–20% faster on lavapipe for ordered input, neutral for shuffled).
    pub no_early_depth_test: bool,
    /// Points each shader invocation rasterizes (0 = default: 32 on a software
    /// adapter, 16 on a GPU with the subgroup reduction, else 8).
    pub points_per_thread: u32,
    /// Each invocation takes consecutive points and merges runs that hit one
    /// pixel into one atomic (64-bit path; see `main_merge` in the shader).
    /// `None`: on for software adapters (lavapipe, 10 M Morton-ordered points at
    /// 1280×720: 88 → 106–110 M points/s), off for GPUs, whose loads coalesce
    /// only when neighbouring invocations read neighbouring points.
    pub merge_runs: Option<bool>,
    /// 1-pixel points reduced across a subgroup before the atomics (64-bit
    /// path, where the adapter has `Features::SUBGROUP`; see `main_subgroup`).
    /// `None`: on for GPUs (NVIDIA H200, 500 M Morton-ordered points: 5.5 →
    /// 3.5 ms a frame), off for software adapters (lavapipe: 10–20% slower).
    pub subgroups: Option<bool>,
    /// With `subgroups`: where a subgroup's points fall on several pixels,
    /// a segmented minimum over runs of one pixel instead of one atomic each.
    pub segmented_runs: bool,
}

impl GpuRasterizer {
    /// Picks the best adapter (hardware before software, Vulkan before GL) and
    /// builds the pipelines. Fails with [`RenderError::NoAdapter`] when none works.
    pub fn new() -> Result<GpuRasterizer, RenderError> {
        Self::with_options(GpuOptions::default())
    }

    /// [`GpuRasterizer::new`] with options.
    pub fn with_options(opts: GpuOptions) -> Result<GpuRasterizer, RenderError> {
        quiet_mesa_layers();
        // Vulkan first; GL (EGL) is only initialized when Vulkan offers no
        // hardware adapter, since a hardware GL device beats a software Vulkan one.
        let from_env = std::env::var_os("WGPU_BACKEND").is_some();
        let allowed = if from_env {
            wgpu::InstanceDescriptor::new_without_display_handle_from_env().backends
        } else {
            wgpu::Backends::VULKAN | wgpu::Backends::GL
        };
        let enumerate = |backends: wgpu::Backends| -> Vec<(u32, wgpu::Adapter)> {
            if backends.is_empty() {
                return Vec::new();
            }
            let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
            desc.backends = backends;
            let instance = wgpu::Instance::new(desc);
            pollster::block_on(instance.enumerate_adapters(backends))
                .into_iter()
                .filter_map(|a| adapter_score(&a).map(|s| (s, a)))
                .collect()
        };
        let mut scored = enumerate(allowed & !wgpu::Backends::GL);
        let has_hardware = scored.iter().any(|(s, _)| *s >= HARDWARE_SCORE);
        if !has_hardware {
            scored.extend(enumerate(allowed & wgpu::Backends::GL));
        }
        scored.sort_by_key(|(s, _)| std::cmp::Reverse(*s));
        if scored.is_empty() {
            return Err(RenderError::NoAdapter(
                "no Vulkan or GL adapter with compute shaders (install mesa-vulkan-drivers for lavapipe)"
                    .into(),
            ));
        }
        let mut last_err = String::new();
        for (_, adapter) in scored {
            // The subgroup path is the default wherever the adapter has the
            // feature: should its device or shader fail on a driver, the
            // adapter still serves without it.
            let retry =
                opts.subgroups.is_none() && adapter.features().contains(wgpu::Features::SUBGROUP);
            match Self::with_adapter(adapter.clone(), opts) {
                Ok(r) => return Ok(r),
                Err(e) => last_err = e.to_string(),
            }
            if retry {
                let plain = GpuOptions {
                    subgroups: Some(false),
                    ..opts
                };
                match Self::with_adapter(adapter, plain) {
                    Ok(r) => return Ok(r),
                    Err(e) => last_err = e.to_string(),
                }
            }
        }
        Err(RenderError::NoAdapter(last_err))
    }

    fn with_adapter(
        adapter: wgpu::Adapter,
        opts: GpuOptions,
    ) -> Result<GpuRasterizer, RenderError> {
        let info = adapter.get_info();
        let want64 = wgpu::Features::SHADER_INT64 | wgpu::Features::SHADER_INT64_ATOMIC_MIN_MAX;
        let all_ops = if !opts.no_early_depth_test {
            wgpu::Features::SHADER_INT64_ATOMIC_ALL_OPS
        } else {
            wgpu::Features::empty()
        };
        let int64 = adapter.features().contains(want64) && !opts.force_32bit_atomics;
        let software = adapter.get_info().device_type == wgpu::DeviceType::Cpu;
        let subgroups = int64
            && adapter.features().contains(wgpu::Features::SUBGROUP)
            && opts.subgroups.unwrap_or(!software);
        let subgroup_feature = if subgroups {
            wgpu::Features::SUBGROUP
        } else {
            wgpu::Features::empty()
        };
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("pcimg render"),
            required_features: if int64 {
                want64 | (adapter.features() & all_ops) | subgroup_feature
            } else {
                wgpu::Features::empty()
            },
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| RenderError::NoAdapter(format!("{}: {e}", info.name)))?;
        let errors: Arc<Mutex<Option<String>>> = Arc::new(Mutex::new(None));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut g) = sink.lock() {
                g.get_or_insert_with(|| e.to_string());
            }
        }));

        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = |src: &str, label: &str| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(src.into()),
            })
        };
        let pipeline = |m: &wgpu::ShaderModule, entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: m,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let early_out = int64
            && adapter
                .features()
                .contains(wgpu::Features::SHADER_INT64_ATOMIC_ALL_OPS)
            && !opts.no_early_depth_test;
        let points_per_thread = match opts.points_per_thread {
            0 if software => SOFTWARE_POINTS_PER_THREAD,
            0 if subgroups => SUBGROUP_POINTS_PER_THREAD,
            0 => DEFAULT_POINTS_PER_THREAD,
            n => n.min(64),
        };
        let merge_runs = opts.merge_runs.unwrap_or(software);
        let raster64 = if early_out {
            RASTERIZE64.replace(
                "// EARLY_OUT",
                "if (atomicLoad(&fb[idx]) <= v) {\n        return;\n    }",
            )
        } else {
            RASTERIZE64.to_string()
        };
        let raster_src = if !int64 {
            RASTERIZE32.to_string()
        } else if subgroups {
            let sg = RASTERIZE_SUBGROUP.replace(
                "const SEGMENTED: bool = false;",
                &format!("const SEGMENTED: bool = {};", opts.segmented_runs),
            );
            let sg = if early_out {
                sg.replace(
                    "// PRETEST",
                    "var near = none;\n            \
                     if (lane == 0u) {\n                \
                     near = u32(atomicLoad(&fb[first]) >> 32u);\n            }\n            \
                     if (subgroupBroadcastFirst(near) < dmin) {\n                \
                     continue;\n            }",
                )
            } else {
                sg
            };
            sg + &raster64
        } else {
            raster64
        }
        .replace(
            "const POINTS_PER_THREAD: u32 = 1u;",
            &format!("const POINTS_PER_THREAD: u32 = {points_per_thread}u;"),
        ) + PROJECT;
        let raster_mod = module(&raster_src, "rasterize");
        let resolve_mod = module(RESOLVE, "resolve");
        let ids_src = [IDS, if int64 { IDS_MATCH64 } else { IDS_MATCH32 }, PROJECT].concat();
        let ids_pipeline = pipeline(&module(&ids_src, "ids"), "main");
        let raster = pipeline(
            &raster_mod,
            if subgroups {
                "main_subgroup"
            } else if int64 && merge_runs {
                "main_merge"
            } else {
                "main"
            },
        );
        let (clear, resolve) = if int64 {
            (
                pipeline(&resolve_mod, "clear64"),
                pipeline(&resolve_mod, "resolve64"),
            )
        } else {
            (
                pipeline(&resolve_mod, "clear32"),
                pipeline(&resolve_mod, "resolve32"),
            )
        };
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(RenderError::Gpu(format!(
                "{}: shader setup failed: {e}",
                info.name
            )));
        }
        let max_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            .max(4);
        let chunk_points = (max_binding / 4).min(1 << 26) as usize;
        Ok(GpuRasterizer {
            device,
            queue,
            info,
            int64,
            raster,
            clear,
            resolve,
            ids_pipeline,
            keep_ids: false,
            ids: Vec::new(),
            chunk_points,
            points_per_thread,
            early_out,
            subgroups,
            max_binding,
            targets: None,
            fb_dirty: true,
            cache: HashMap::new(),
            cache_budget: DEFAULT_CACHE_BUDGET,
            frame: 0,
            errors,
        })
    }

    /// Whether the 64-bit atomic framebuffer is in use (else 16-bit depth + BGR565).
    pub fn has_int64_atomics(&self) -> bool {
        self.int64
    }

    /// Whether 1-pixel points are reduced across subgroups before the atomics.
    pub fn has_subgroups(&self) -> bool {
        self.subgroups
    }

    /// Whether the rasterizer pre-tests depth with a plain atomic load before
    /// `atomicMin` (needs `SHADER_INT64_ATOMIC_ALL_OPS`).
    pub fn has_early_depth_test(&self) -> bool {
        self.early_out
    }

    /// The adapter in use.
    pub(crate) fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }

    /// Points per storage buffer (and per dispatch).
    pub fn chunk_points(&self) -> usize {
        self.chunk_points
    }

    /// Limits chunks to `n` points (at most the binding limit); drops the cache.
    pub fn set_chunk_points(&mut self, n: usize) {
        self.chunk_points = n.clamp(1, (self.max_binding / 4) as usize);
        self.cache.clear();
    }

    /// Sets how many bytes of point buffers may stay on the device for batches
    /// that the last frame did not draw (least recently used are dropped
    /// first). Batches of the current frame are always kept. Default 1 GiB.
    pub fn set_cache_budget(&mut self, bytes: u64) {
        self.cache_budget = bytes;
    }

    /// Bytes of point buffers currently cached on the device.
    pub fn cached_bytes(&self) -> u64 {
        self.cache.values().map(|e| e.bytes).sum()
    }

    /// Drops all cached point buffers (call when column memory is reused in place).
    pub fn invalidate_cache(&mut self) {
        self.cache.clear();
    }

    fn take_error(&self) -> Option<String> {
        self.errors.lock().ok().and_then(|mut g| g.take())
    }

    fn targets(&mut self, width: u32, height: u32) -> Result<(), RenderError> {
        if let Some(t) = &self.targets
            && t.width == width
            && t.height == height
        {
            return Ok(());
        }
        let px = width as u64 * height as u64;
        // Padded to whole quads of 4 pixels for the vectorized resolve.
        let px = px.next_multiple_of(4);
        let fb_bytes = px * if self.int64 { 8 } else { 4 };
        if fb_bytes > self.max_binding {
            return Err(RenderError::InvalidOptions(format!(
                "{width}x{height} needs a {fb_bytes}-byte framebuffer, above the adapter's {} binding limit",
                self.max_binding
            )));
        }
        let d = &self.device;
        let buf = |label: &str, size: u64, usage: wgpu::BufferUsages| {
            d.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let fb = buf("framebuffer", fb_bytes, U::STORAGE);
        // RGBA then depth, 4 bytes each per pixel; depth starts 256-aligned.
        let depth_offset = depth_offset(px);
        let out = buf("resolved", depth_offset + px * 4, U::STORAGE | U::COPY_SRC);
        let staging = buf("staging", depth_offset + px * 4, U::MAP_READ | U::COPY_DST);
        let resolve_params = buf("resolve params", 32, U::UNIFORM | U::COPY_DST);
        let raster_bg = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("raster fb"),
            layout: &self.raster.get_bind_group_layout(1),
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: fb.as_entire_binding(),
            }],
        });
        let fb_binding = if self.int64 { 1 } else { 2 };
        let clear_bg = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("clear"),
            layout: &self.clear.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: resolve_params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: fb_binding,
                    resource: fb.as_entire_binding(),
                },
            ],
        });
        let half = wgpu::BufferSize::new(px * 4);
        let resolve_bg = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("resolve"),
            layout: &self.resolve.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: resolve_params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: fb_binding,
                    resource: fb.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &out,
                        offset: 0,
                        size: half,
                    }),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &out,
                        offset: depth_offset,
                        size: half,
                    }),
                },
            ],
        });
        self.fb_dirty = true;
        self.targets = Some(Targets {
            width,
            height,
            resolve_params,
            out,
            staging,
            raster_bg,
            clear_bg,
            resolve_bg,
            fb,
            ids: None,
        });
        Ok(())
    }

    /// Makes the id buffer for the current frame size, once.
    fn id_targets(&mut self) {
        let Some(t) = self.targets.as_mut() else {
            return;
        };
        if t.ids.is_some() {
            return;
        }
        let bytes = (t.width as u64 * t.height as u64).next_multiple_of(4) * 4;
        let buf = |label: &str, usage: wgpu::BufferUsages| {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let ids = buf("ids", U::STORAGE | U::COPY_SRC | U::COPY_DST);
        let staging = buf("ids staging", U::MAP_READ | U::COPY_DST);
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ids"),
            layout: &self.ids_pipeline.get_bind_group_layout(1),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: ids.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: t.fb.as_entire_binding(),
                },
            ],
        });
        t.ids = Some(IdTargets {
            buf: ids,
            staging,
            bind_group,
        });
    }

    /// Uploads `b` unless cached; returns whether it uploaded.
    fn upload(&mut self, b: &PointBatch<'_>) -> bool {
        let key = batch_key(b);
        let fp = fingerprint(b);
        let frame = self.frame;
        if let Some(e) = self.cache.get_mut(&key)
            && e.fingerprint == fp
        {
            e.last_used = frame;
            return false;
        }
        let d = &self.device;
        let layout = self.raster.get_bind_group_layout(0);
        let ids_layout = self.ids_pipeline.get_bind_group_layout(0);
        let mut chunks = Vec::new();
        let n = b.len();
        let mut s = 0;
        while s < n {
            let e = (s + self.chunk_points).min(n);
            let mk = |label: &str, bytes: &[u8]| {
                let buffer = d.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: bytes.len() as u64,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                self.queue.write_buffer(&buffer, 0, bytes);
                buffer
            };
            let bx = mk("x", bytemuck::cast_slice(&b.x[s..e]));
            let by = mk("y", bytemuck::cast_slice(&b.y[s..e]));
            let bz = mk("z", bytemuck::cast_slice(&b.z[s..e]));
            let bc = mk("color", bytemuck::cast_slice(&b.color[s..e]));
            let params = d.create_buffer(&wgpu::BufferDescriptor {
                label: Some("raster params"),
                size: std::mem::size_of::<RasterParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let bind = |label: &str, layout: &wgpu::BindGroupLayout| {
                d.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some(label),
                    layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: params.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: bx.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: by.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 3,
                            resource: bz.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 4,
                            resource: bc.as_entire_binding(),
                        },
                    ],
                })
            };
            let bind_group = bind("points", &layout);
            let ids_bind_group = bind("points (ids)", &ids_layout);
            chunks.push(Chunk {
                count: (e - s) as u32,
                start: s as u32,
                params,
                bind_group,
                ids_bind_group,
                _buffers: [bx, by, bz, bc],
            });
            s = e;
        }
        self.cache.insert(
            key,
            CacheEntry {
                fingerprint: fp,
                bytes: n as u64 * 16,
                chunks,
                last_used: frame,
            },
        );
        true
    }

    /// Drops least recently used entries not drawn in `frame` until those
    /// left fit the budget.
    fn evict(&mut self, frame: u64) {
        let mut stale: Vec<(u64, u64, Key)> = self
            .cache
            .iter()
            .filter(|(_, e)| e.last_used != frame)
            .map(|(k, e)| (e.last_used, e.bytes, *k))
            .collect();
        let mut total: u64 = stale.iter().map(|s| s.1).sum();
        if total <= self.cache_budget {
            return;
        }
        stale.sort_unstable();
        for (_, bytes, key) in stale {
            if total <= self.cache_budget {
                break;
            }
            self.cache.remove(&key);
            total -= bytes;
        }
    }

    fn wait(&self) -> Result<(), RenderError> {
        self.device
            .poll(wgpu::PollType::Wait {
                submission_index: None,
                timeout: Some(GPU_TIMEOUT),
            })
            .map(|_| ())
            .map_err(|e| RenderError::Gpu(format!("waiting for the device: {e}")))
    }
}

/// Byte offset of the depth plane in the resolved buffer (aligned for binding).
/// A device id tag (`0xffffffff - frame-wide index`, 0: none) as the
/// [`pick::point_id`] of that point, `starts` giving each batch's first index.
fn frame_id(tag: u32, starts: &[u64]) -> u64 {
    if tag == 0 {
        return pick::NO_POINT;
    }
    let g = (u32::MAX - tag) as u64;
    // The last batch starting at or before `g` (empty batches share starts).
    let bi = starts.partition_point(|&s| s <= g).saturating_sub(1);
    pick::point_id(bi, (g - starts[bi]) as usize)
}

fn depth_offset(pixels: u64) -> u64 {
    (pixels * 4).next_multiple_of(256)
}

fn pack_background(bg: [u8; 3]) -> u32 {
    bg[0] as u32 | (bg[1] as u32) << 8 | (bg[2] as u32) << 16 | 0xff00_0000
}

impl Rasterizer for GpuRasterizer {
    fn keep_ids(&mut self, on: bool) -> bool {
        self.keep_ids = on;
        true
    }

    fn last_ids(&self) -> Option<&[u64]> {
        (self.keep_ids && !self.ids.is_empty()).then_some(self.ids.as_slice())
    }

    fn name(&self) -> String {
        let backend = match self.info.backend {
            wgpu::Backend::Vulkan => "Vulkan",
            wgpu::Backend::Gl => "GL",
            wgpu::Backend::Metal => "Metal",
            wgpu::Backend::Dx12 => "DX12",
            wgpu::Backend::BrowserWebGpu => "WebGPU",
            wgpu::Backend::Noop => "noop",
        };
        let driver = if self.info.driver_info.is_empty() {
            String::new()
        } else {
            format!(" ({})", self.info.driver_info)
        };
        let atomics = if self.int64 { "" } else { ", 32-bit atomics" };
        format!("wgpu {backend}: {}{driver}{atomics}", self.info.name)
    }

    fn render(
        &mut self,
        camera: &Camera,
        batches: &[PointBatch<'_>],
        opts: &RenderOptions,
    ) -> Result<Frame, RenderError> {
        let point_size = opts.validate()?;
        let total = total_points(batches)?;
        let (w, h) = (opts.width, opts.height);
        self.targets(w, h)?;
        // Ids are u32 on the device, 0xffffffff reserved for "no point".
        let with_ids = self.keep_ids && (total as u64) < u32::MAX as u64;
        self.ids.clear();
        if with_ids {
            self.id_targets();
        }
        self.frame += 1;

        // Upload (or find cached) point buffers.
        let tu = Instant::now();
        let mut uploaded = false;
        for b in batches.iter().filter(|b| !b.is_empty()) {
            uploaded |= self.upload(b);
        }
        let frame = self.frame;
        self.evict(frame);
        if uploaded {
            self.queue.submit(None);
            self.wait()?;
        }
        let upload_ms = if uploaded {
            tu.elapsed().as_secs_f64() * 1e3
        } else {
            0.0
        };

        let t0 = Instant::now();
        let aspect = opts.aspect();
        let px = w * h;
        let quads = px.div_ceil(4);
        let (ngx, ngy, _) = dispatch_shape(quads);
        let Some(t) = self.targets.as_ref() else {
            return Err(RenderError::Gpu("framebuffer missing".into()));
        };
        // 16-bit log depth of the 32-bit path spans [near, far].
        let (near, far) = camera.near_far();
        let log2_near = near.log2() as f32;
        let depth_scale = (65534.0 / (far / near).log2().max(1e-6)) as f32;
        self.queue.write_buffer(
            &t.resolve_params,
            0,
            bytemuck::bytes_of(&ResolveParams {
                quads,
                background: pack_background(opts.background),
                log2_near,
                depth_scale,
                _unused: 0,
                write_depth: opts.eye_dome_lighting as u32,
                _pad: [0; 2],
            }),
        );
        let mut work: Vec<(&Chunk, (u32, u32))> = Vec::new();
        // Where each batch's points start in the frame-wide id numbering.
        let mut starts = Vec::with_capacity(batches.len());
        let mut next = 0u64;
        for b in batches {
            starts.push(next);
            next += b.len() as u64;
        }
        for (bi, b) in batches.iter().enumerate().filter(|(_, b)| !b.is_empty()) {
            let Some(entry) = self.cache.get(&batch_key(b)) else {
                continue;
            };
            let mvp = camera.view_proj_aspect(b.origin, aspect).to_cols_array();
            for c in &entry.chunks {
                let (gx, gy, _) = dispatch_shape(c.count.div_ceil(self.points_per_thread));
                let p = RasterParams {
                    mvp,
                    width: w,
                    height: h,
                    point_size,
                    count: c.count,
                    hw: w as f32 * 0.5,
                    hh: h as f32 * 0.5,
                    off: (point_size as f32 - 1.0) * 0.5,
                    log2_near,
                    depth_scale,
                    id_base: (starts[bi] + c.start as u64).min(u32::MAX as u64) as u32,
                    _pad: [0; 2],
                };
                self.queue
                    .write_buffer(&c.params, 0, bytemuck::bytes_of(&p));
                work.push((c, (gx, gy)));
            }
        }
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        if self.fb_dirty {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("clear"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.clear);
            pass.set_bind_group(0, &t.clear_bg, &[]);
            pass.dispatch_workgroups(ngx, ngy, 1);
        }
        // Until this frame's resolve is known to have run.
        self.fb_dirty = true;
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("rasterize"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.raster);
            pass.set_bind_group(1, &t.raster_bg, &[]);
            for (c, (gx, gy)) in &work {
                pass.set_bind_group(0, &c.bind_group, &[]);
                pass.dispatch_workgroups(*gx, *gy, 1);
            }
        }
        let ids = t.ids.as_ref().filter(|_| with_ids);
        if let Some(it) = ids {
            enc.clear_buffer(&it.buf, 0, None);
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("ids"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.ids_pipeline);
            pass.set_bind_group(1, &it.bind_group, &[]);
            for (c, _) in &work {
                let (gx, gy, _) = dispatch_shape(c.count);
                pass.set_bind_group(0, &c.ids_bind_group, &[]);
                pass.dispatch_workgroups(gx, gy, 1);
            }
        }
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("resolve"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.resolve);
            pass.set_bind_group(0, &t.resolve_bg, &[]);
            pass.dispatch_workgroups(ngx, ngy, 1);
        }
        let depth_at = depth_offset(quads as u64 * 4);
        let read_bytes = if opts.eye_dome_lighting {
            depth_at + px as u64 * 4
        } else {
            px as u64 * 4
        };
        enc.copy_buffer_to_buffer(&t.out, 0, &t.staging, 0, read_bytes);
        let id_bytes = px as u64 * 4;
        if let Some(it) = ids {
            enc.copy_buffer_to_buffer(&it.buf, 0, &it.staging, 0, id_bytes);
        }
        self.queue.submit(Some(enc.finish()));

        let slice = t.staging.slice(..read_bytes);
        let (tx, rx) = std::sync::mpsc::channel();
        let tx2 = tx.clone();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        let id_slice = ids.map(|it| it.staging.slice(..id_bytes));
        if let Some(s) = &id_slice {
            s.map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx2.send(r);
            });
        } else {
            drop(tx2);
        }
        self.wait()?;
        for _ in 0..1 + id_slice.is_some() as usize {
            match rx.try_recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    return Err(RenderError::Gpu(format!("reading back the frame: {e}")));
                }
                Err(_) => return Err(RenderError::Gpu("frame readback did not complete".into())),
            }
        }
        if let (Some(s), Some(it)) = (&id_slice, ids) {
            let read = s.get_mapped_range().map(|view| {
                view.chunks_exact(4)
                    .map(|c| frame_id(u32::from_le_bytes([c[0], c[1], c[2], c[3]]), &starts))
                    .collect::<Vec<u64>>()
            });
            it.staging.unmap();
            self.ids = read.map_err(|e| RenderError::Gpu(format!("mapping the ids: {e}")))?;
        }
        let read = slice.get_mapped_range().map(|view| {
            let rgba = view[..px as usize * 4].to_vec();
            let depth: Vec<f32> = if opts.eye_dome_lighting {
                view[depth_at as usize..]
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect()
            } else {
                Vec::new()
            };
            (rgba, depth)
        });
        t.staging.unmap();
        let (mut rgba, depth) =
            read.map_err(|e| RenderError::Gpu(format!("mapping the frame: {e}")))?;
        if let Some(e) = self.take_error() {
            return Err(RenderError::Gpu(e));
        }
        self.fb_dirty = false;
        if opts.eye_dome_lighting {
            edl::apply(&mut rgba, &depth, w, h, &opts.edl);
        }
        Ok(Frame {
            width: w,
            height: h,
            rgba,
            stats: FrameStats {
                points_drawn: total as u64,
                render_ms: t0.elapsed().as_secs_f64() * 1e3,
                upload_ms,
            },
        })
    }
}
