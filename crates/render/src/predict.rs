//! The isosurface prediction buffer (Braley et al.): its settings, its per-pixel
//! history (ping-pong, per viewport; owned by `frame.rs` as part of group 0) and
//! its statistics. The method and its failure analysis are in
//! `docs/prediction.md`; the traversals in `shaders/incore_predict.wgsl` and
//! `shaders/ooc_predict.wgsl`.

use crate::error::RenderError;
use crate::gpu;
use brickray_core::{Camera, RenderMode, VolumeFrame};
use thiserror::Error;

/// Settings of the isosurface prediction buffer (iso mode, in core and out of
/// core).
///
/// Each pixel keeps last frame's hit (or a flag) and picks a traversal: local
/// (outward from the predicted t), sparse (a coarse march, bisected) or full.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prediction {
    /// Every `alpha` frames all pixels take the full traversal (paper: 10).
    pub alpha: u32,
    /// Sparse step = the smallest voxel / `kappa` (paper: 0.5).
    pub kappa: f32,
    /// Most steps (of the full traversal's length) the local search takes in
    /// each direction before it falls back to the sparse traversal.
    pub local_steps: u32,
    /// The first-hit guard: a local hit is accepted only when the macro cells in
    /// front of it cannot hold the isovalue (else the full traversal runs).
    pub guard: bool,
    /// Empty-space skipping in the sparse traversal.
    pub sparse_ess: bool,
    /// Reprojection: last frame's hits are warped into this frame's view (a
    /// scatter pass before the ray cast; holes take the sparse traversal), so
    /// translation and zoom keep their coherence.
    pub reproject: bool,
}

impl Prediction {
    /// The paper's method: alpha 10, kappa 0.5, no guard, no skipping in the
    /// sparse traversal.
    pub const PAPER: Prediction = Prediction {
        alpha: 10,
        kappa: 0.5,
        local_steps: 16,
        guard: false,
        sparse_ess: false,
        reproject: false,
    };
    /// Accepted range of `alpha`.
    pub const ALPHA: (u32, u32) = (1, 100_000);
    /// Accepted range of `kappa` (below 1/16 the sparse step is 16 voxels).
    pub const KAPPA: (f32, f32) = (1.0 / 16.0, 16.0);
    /// Accepted range of `local_steps`.
    pub const LOCAL_STEPS: (u32, u32) = (1, 4096);

    /// Checks every field against its range.
    pub fn validate(&self) -> Result<(), PredictionError> {
        let out = |field, value: f64, min: f64, max: f64| {
            if value.is_finite() && (min..=max).contains(&value) {
                Ok(())
            } else {
                Err(PredictionError::OutOfRange {
                    field,
                    value,
                    min,
                    max,
                })
            }
        };
        out(
            "alpha",
            self.alpha as f64,
            Self::ALPHA.0 as f64,
            Self::ALPHA.1 as f64,
        )?;
        out(
            "kappa",
            self.kappa as f64,
            Self::KAPPA.0 as f64,
            Self::KAPPA.1 as f64,
        )?;
        out(
            "local_steps",
            self.local_steps as f64,
            Self::LOCAL_STEPS.0 as f64,
            Self::LOCAL_STEPS.1 as f64,
        )
    }
}

impl Default for Prediction {
    fn default() -> Self {
        Prediction::PAPER
    }
}

/// A prediction setting outside its range.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[non_exhaustive]
pub enum PredictionError {
    /// A value is NaN, infinite or outside its documented range.
    #[error("prediction {field} = {value} is outside {min}..={max}")]
    OutOfRange {
        /// The setting.
        field: &'static str,
        /// Its value.
        value: f64,
        /// Smallest accepted value.
        min: f64,
        /// Largest accepted value.
        max: f64,
    },
}

/// Which traversal a pixel took (`TRAVERSAL_*` in predict.wgsl).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum TraversalClass {
    /// The ray missed the volume's box: not traversed.
    None = 0,
    /// Local search from the prediction, accepted.
    Local = 1,
    /// Local search found nothing: sparse traversal from the ray start.
    LocalMissed = 2,
    /// Local hit rejected by the first-hit guard: full traversal.
    GuardRejected = 3,
    /// No surface last frame: sparse traversal.
    Sparse = 4,
    /// No information or a refresh frame: full traversal.
    Full = 5,
}

impl TraversalClass {
    /// Every class with its WGSL name, in code order.
    pub const ALL: [(&'static str, TraversalClass); 6] = [
        ("TRAVERSAL_NONE", TraversalClass::None),
        ("TRAVERSAL_LOCAL", TraversalClass::Local),
        ("TRAVERSAL_LOCAL_MISSED", TraversalClass::LocalMissed),
        ("TRAVERSAL_GUARD_REJECTED", TraversalClass::GuardRejected),
        ("TRAVERSAL_SPARSE", TraversalClass::Sparse),
        ("TRAVERSAL_FULL", TraversalClass::Full),
    ];

    /// The class of a code read back from [`crate::VolumeRenderer::prediction_classes`].
    pub fn from_code(code: u32) -> Option<TraversalClass> {
        Self::ALL.get(code as usize).map(|(_, c)| *c)
    }

    /// A debug colour per class (the prediction-buffer image, as the paper's
    /// Figure 1): black none, green local, yellow local missed, red guard
    /// rejected, blue sparse, white full.
    pub fn debug_color(self) -> [u8; 3] {
        match self {
            TraversalClass::None => [0, 0, 0],
            TraversalClass::Local => [40, 200, 60],
            TraversalClass::LocalMissed => [230, 210, 40],
            TraversalClass::GuardRejected => [220, 40, 40],
            TraversalClass::Sparse => [50, 90, 230],
            TraversalClass::Full => [240, 240, 240],
        }
    }
}

/// Pixels per traversal class of one frame (from the classes read back).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PredictionCounts {
    /// Pixels per class, indexed by the class's code.
    pub pixels: [u64; 6],
}

impl PredictionCounts {
    /// Counts the class codes of a frame; unknown codes are an error.
    pub fn from_codes(codes: &[u32]) -> Option<PredictionCounts> {
        let mut c = PredictionCounts::default();
        for &k in codes {
            *c.pixels.get_mut(k as usize)? += 1;
        }
        Some(c)
    }

    /// Pixels of `class`.
    pub fn of(&self, class: TraversalClass) -> u64 {
        self.pixels[class as usize]
    }
}

/// `struct Predict` of predict.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct PredictUniforms {
    pub(crate) read_off: u32,
    pub(crate) write_off: u32,
    pub(crate) class_off: u32,
    pub(crate) refresh: u32,
    pub(crate) local_steps: u32,
    pub(crate) sparse_refine: u32,
    pub(crate) sparse_dt: f32,
    pub(crate) reprojected: u32,
}

/// A camera's basis in world space (as `RayGen`), for reprojection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Basis {
    eye: [f32; 3],
    fwd: [f32; 3],
    right: [f32; 3],
    up: [f32; 3],
    near: f32,
    perspective: bool,
}

impl Basis {
    pub(crate) fn of(desc: &crate::FrameDesc<'_>) -> Basis {
        let r = desc.camera.rays(desc.viewport.aspect());
        let v = |x: glam::DVec3| x.as_vec3().to_array();
        Basis {
            eye: v(r.eye),
            fwd: v(r.fwd),
            right: v(r.right),
            up: v(r.up),
            near: r.near as f32,
            perspective: r.perspective,
        }
    }
}

/// `struct Reproject` of reproject.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct ReprojectUniforms {
    pub(crate) prev_eye: [f32; 3],
    pub(crate) prev_perspective: u32,
    pub(crate) prev_fwd: [f32; 3],
    pub(crate) prev_near: f32,
    pub(crate) prev_right: [f32; 3],
    pub(crate) pad0: f32,
    pub(crate) prev_up: [f32; 3],
    pub(crate) pad1: f32,
    pub(crate) eye: [f32; 3],
    pub(crate) perspective: u32,
    pub(crate) fwd: [f32; 3],
    pub(crate) near: f32,
    pub(crate) right: [f32; 3],
    pub(crate) pad2: f32,
    pub(crate) up: [f32; 3],
    pub(crate) pad3: f32,
    pub(crate) size: [u32; 2],
    pub(crate) read_off: u32,
    pub(crate) write_off: u32,
}

impl ReprojectUniforms {
    pub(crate) fn new(
        prev: Basis,
        cur: Basis,
        size: [u32; 2],
        read_off: u32,
        write_off: u32,
    ) -> Self {
        ReprojectUniforms {
            prev_eye: prev.eye,
            prev_perspective: prev.perspective as u32,
            prev_fwd: prev.fwd,
            prev_near: prev.near,
            prev_right: prev.right,
            pad0: 0.0,
            prev_up: prev.up,
            pad1: 0.0,
            eye: cur.eye,
            perspective: cur.perspective as u32,
            fwd: cur.fwd,
            near: cur.near,
            right: cur.right,
            pad2: 0.0,
            up: cur.up,
            pad3: 0.0,
            size,
            read_off,
            write_off,
        }
    }
}

/// Layout of the reprojection pass: the history (0) and its uniforms (1).
pub(crate) fn reproject_layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    vec![
        gpu::storage_entry(0, false),
        gpu::uniform_entry::<ReprojectUniforms>(1),
    ]
}

/// The reprojection pass: its pipeline, uniforms and bind group (over one
/// history buffer), made when reprojection is first used.
#[derive(Debug)]
pub(crate) struct Reprojector {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    uniform: gpu::Uniform<ReprojectUniforms>,
    /// The bind group and the history generation it binds.
    bind_group: Option<(wgpu::BindGroup, u64)>,
}

impl Reprojector {
    pub(crate) fn new(device: &wgpu::Device) -> Result<Reprojector, RenderError> {
        let label = "brickray-render prediction reprojection";
        let (layout, pipeline) = gpu::single_group_pipeline(
            device,
            label,
            &reproject_layout_entries(),
            crate::shaders::REPROJECT,
        )?;
        Ok(Reprojector {
            layout,
            pipeline,
            uniform: gpu::Uniform::new(device, "brickray-render reprojection uniforms")?,
            bind_group: None,
        })
    }

    /// Records the warp of `history`'s last entries (at `u.read_off`) into its
    /// reprojection region (at `u.write_off`, cleared first). Returns the bytes
    /// written.
    pub(crate) fn record(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        history: &History,
        generation: u64,
        u: ReprojectUniforms,
    ) -> Result<u64, RenderError> {
        let written = self.uniform.write(queue, u);
        if self
            .bind_group
            .as_ref()
            .is_none_or(|(_, g)| *g != generation)
        {
            let bg = gpu::scoped(device, "brickray-render reprojection bind group", || {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("brickray-render reprojection"),
                    layout: &self.layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: history.buffer.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: self.uniform.buffer.as_entire_binding(),
                        },
                    ],
                })
            })?;
            self.bind_group = Some((bg, generation));
        }
        let n = history.pixels as u64 * 4;
        encoder.clear_buffer(&history.buffer, u.write_off as u64 * 4, Some(n));
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("brickray-render prediction reprojection"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, self.bind_group.as_ref().map(|(b, _)| b), &[]);
        pass.dispatch_workgroups(
            u.size[0].div_ceil(crate::gpu::WORKGROUP[0]),
            u.size[1].div_ceil(crate::gpu::WORKGROUP[1]),
            1,
        );
        Ok(written)
    }
}

/// What invalidates the history: a change of any of these clears it (the next
/// frame takes the full traversal everywhere). The camera's pose is not part of
/// it: that is the coherence the prediction exploits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct HistoryKey {
    pub(crate) size: [u32; 2],
    /// Every render setting (the isovalue, the step, and any later one such as
    /// a clip box): a change of any of them clears the history.
    pub(crate) render: brickray_core::RenderSettings,
    pub(crate) volume: u64,
    pub(crate) frame: VolumeFrame,
    pub(crate) projection: brickray_core::Projection,
    pub(crate) host_depth: bool,
    pub(crate) settings: Prediction,
}

impl HistoryKey {
    pub(crate) fn new(
        desc: &crate::FrameDesc<'_>,
        volume: u64,
        settings: Prediction,
    ) -> Option<HistoryKey> {
        let RenderMode::Iso { .. } = desc.settings.mode else {
            return None;
        };
        let c: &Camera = &desc.camera;
        Some(HistoryKey {
            size: [desc.viewport.width, desc.viewport.height],
            render: desc.settings,
            volume,
            frame: desc.frame,
            projection: c.projection,
            host_depth: desc.host_depth.is_some(),
            settings,
        })
    }
}

/// The per-viewport history: one buffer holding last frame's entries, this
/// frame's entries (the halves swap every frame) and the traversal classes.
#[derive(Debug)]
pub(crate) struct History {
    pub(crate) buffer: wgpu::Buffer,
    pub(crate) pixels: u32,
    /// Which half this frame reads.
    pub(crate) parity: u32,
    /// Frames since the history was cleared.
    pub(crate) frames: u64,
    pub(crate) key: Option<HistoryKey>,
    /// The camera of the frame that wrote the last entries (reprojection).
    pub(crate) basis: Option<Basis>,
}

impl History {
    /// A cleared history for `pixels` pixels (4 u32 per pixel: two halves of
    /// entries, the classes, the reprojected entries).
    pub(crate) fn new(device: &wgpu::Device, pixels: u32) -> Result<History, RenderError> {
        let size = (pixels as u64 * 4 * 4).max(16);
        let l = device.limits();
        gpu::need(
            "max_storage_buffer_binding_size",
            size,
            l.max_storage_buffer_binding_size,
        )?;
        gpu::need("max_buffer_size", size, l.max_buffer_size)?;
        let buffer = gpu::scoped(device, "brickray-render prediction history", || {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("brickray-render prediction history"),
                size,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_DST
                    | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        })?;
        Ok(History {
            buffer,
            pixels,
            parity: 0,
            frames: 0,
            key: None,
            basis: None,
        })
    }

    /// Byte offset and size of the traversal classes.
    pub(crate) fn classes(&self) -> (u64, u64) {
        let n = self.pixels as u64 * 4;
        (2 * n, n)
    }
}
