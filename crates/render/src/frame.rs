//! Group 0 of every ray-cast kernel: the frame's uniforms, the host's depth and
//! the per-viewport outputs (colour, depth, sample counts) and the isosurface
//! prediction history (`predict.rs`), with their bind group.

use crate::desc::{FrameDesc, Viewport};
use crate::error::{HostDepthError, PrepareError, RenderError};
use crate::gpu::{self, Uniform};
use crate::predict::{
    Basis, History, HistoryKey, PredictUniforms, Prediction, ReprojectUniforms, Reprojector,
};
use brickray_core::{DepthConvention, RenderMode, RenderSettings};
use glam::{DMat3, DVec3};

/// Whether the frame's DVR grows its step as the transmittance falls
/// (`Accel::adaptive_step`, DVR without pre-integration): then the corrected
/// table needs [`brickray_core::ADAPTIVE_STEP_DOUBLINGS`] rows more.
pub(crate) fn adaptive_step(s: &RenderSettings) -> bool {
    s.accel.adaptive_step && matches!(s.mode, RenderMode::Dvr) && !s.preintegrated
}

/// The corrected tables' rows past the step lengths' for the frame's
/// settings: one per doubling of the adaptive step ([`adaptive_step`]).
pub(crate) fn adaptive_rows(s: &RenderSettings) -> u32 {
    if adaptive_step(s) {
        brickray_core::ADAPTIVE_STEP_DOUBLINGS
    } else {
        0
    }
}

/// Bits of [`FrameUniforms::flags`] (`FLAG_*` in common.wgsl).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(transparent)]
pub(crate) struct FrameFlags(pub(crate) u32);

impl FrameFlags {
    /// Rays stop at the host's depth.
    pub(crate) const HOST_DEPTH: FrameFlags = FrameFlags(1);
    /// Perspective projection (else orthographic).
    pub(crate) const PERSPECTIVE: FrameFlags = FrameFlags(2);
    /// Reversed-Z depth.
    pub(crate) const REVERSED_Z: FrameFlags = FrameFlags(4);
    /// DVR's step grows as the transmittance falls (`Accel::adaptive_step`;
    /// never with pre-integration).
    pub(crate) const ADAPTIVE_STEP: FrameFlags = FrameFlags(8);
    /// Every flag with its WGSL name, for the reflection test.
    #[cfg(test)]
    pub(crate) const ALL: [(&'static str, FrameFlags); 4] = [
        ("FLAG_HOST_DEPTH", Self::HOST_DEPTH),
        ("FLAG_PERSPECTIVE", Self::PERSPECTIVE),
        ("FLAG_REVERSED_Z", Self::REVERSED_Z),
        ("FLAG_ADAPTIVE_STEP", Self::ADAPTIVE_STEP),
    ];

    fn set(&mut self, f: FrameFlags, on: bool) {
        if on {
            self.0 |= f.0;
        }
    }
}

/// `struct Frame` of common.wgsl: the per-frame uniforms, named field for field
/// (a test reflects the WGSL and checks every offset).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct FrameUniforms {
    pub(crate) eye_tex: [f32; 3],
    pub(crate) near: f32,
    pub(crate) fwd_tex: [f32; 3],
    pub(crate) depth_a: f32,
    pub(crate) right_tex: [f32; 3],
    pub(crate) depth_b: f32,
    pub(crate) up_tex: [f32; 3],
    pub(crate) dt: f32,
    pub(crate) fwd_world: [f32; 3],
    pub(crate) step_factor: f32,
    pub(crate) right_world: [f32; 3],
    pub(crate) ert_threshold: f32,
    pub(crate) up_world: [f32; 3],
    pub(crate) depth_opacity: f32,
    pub(crate) iso_color: [f32; 3],
    pub(crate) isovalue: f32,
    pub(crate) normal_mat: [[f32; 4]; 3],
    pub(crate) viewport_origin: [u32; 2],
    pub(crate) viewport_size: [u32; 2],
    pub(crate) flags: FrameFlags,
    pub(crate) iso_refine_steps: u32,
    pub(crate) max_samples: u32,
    pub(crate) max_leaves: u32,
    pub(crate) ambient: f32,
    pub(crate) diffuse: f32,
    pub(crate) specular: f32,
    pub(crate) shininess: f32,
    pub(crate) clip_min: [f32; 3],
    pub(crate) clip_pad_a: f32,
    pub(crate) clip_max: [f32; 3],
    pub(crate) clip_pad_b: f32,
    /// The intensity window in normalized values (MIP and slices).
    pub(crate) window_lo: f32,
    pub(crate) window_hi: f32,
    /// `MAP_*` of common.wgsl: 0 maps MIP through the transfer function.
    pub(crate) color_map: u32,
    /// `SLAB_*` of slice.wgsl: how a slice's slab reduces its samples.
    pub(crate) slab_mode: u32,
    /// Samples across a slice's slab and their spacing (ray parameter).
    pub(crate) slab_samples: u32,
    pub(crate) slab_dt: f32,
    pub(crate) map_pad_a: f32,
    pub(crate) map_pad_b: f32,
}

/// Upper bound of samples (and skips) along one ray as a multiple of the samples
/// a ray across the box's diagonal takes: a guard against degenerate input, never
/// reached by a valid frame.
const SAMPLE_GUARD_FACTOR: f64 = 2.0;

impl FrameUniforms {
    /// The uniforms of a validated frame. `max_leaves` bounds the index leaves one
    /// ray may visit (out of core; 0 in core).
    pub(crate) fn new(desc: &FrameDesc<'_>, max_leaves: u32) -> FrameUniforms {
        let s: &RenderSettings = &desc.settings;
        let vp = desc.viewport;
        let rays = desc.camera.rays(vp.aspect());
        let model = desc.frame.model.as_dmat4();
        let inv_model = model.inverse();
        let tex = |v: DVec3| inv_model.transform_vector3(v).as_vec3().to_array();
        let world = |v: DVec3| v.as_vec3().to_array();
        let normal = DMat3::from_mat4(model).inverse().transpose();
        let voxel_world = desc.frame.voxel_world as f64;
        let dt = s.step_factor as f64 * voxel_world;
        let diagonal = desc.frame.world_size().as_dvec3().length();
        let max_samples =
            (SAMPLE_GUARD_FACTOR * (diagonal / dt).ceil() + 64.0).min(u32::MAX as f64) as u32;
        let mut flags = FrameFlags::default();
        flags.set(FrameFlags::HOST_DEPTH, desc.host_depth.is_some());
        flags.set(FrameFlags::PERSPECTIVE, rays.perspective);
        flags.set(
            FrameFlags::REVERSED_Z,
            desc.camera.depth == DepthConvention::ReversedZ,
        );
        flags.set(FrameFlags::ADAPTIVE_STEP, adaptive_step(s));
        let (isovalue, iso_color) = match s.mode {
            RenderMode::Iso { value, color } => (value, color),
            _ => (0.0, [0.0; 3]),
        };
        FrameUniforms {
            eye_tex: inv_model.transform_point3(rays.eye).as_vec3().to_array(),
            near: rays.near as f32,
            fwd_tex: tex(rays.fwd),
            depth_a: rays.depth.a as f32,
            right_tex: tex(rays.right),
            depth_b: rays.depth.b as f32,
            up_tex: tex(rays.up),
            dt: dt as f32,
            fwd_world: world(rays.fwd),
            step_factor: s.step_factor,
            right_world: world(rays.right),
            // Above any opacity: never terminates.
            ert_threshold: s.accel.early_termination.unwrap_or(2.0),
            up_world: world(rays.up),
            depth_opacity: s.depth_opacity,
            iso_color,
            isovalue,
            normal_mat: [0, 1, 2].map(|i| {
                let c = normal.col(i).as_vec3();
                [c.x, c.y, c.z, 0.0]
            }),
            viewport_origin: [vp.x, vp.y],
            viewport_size: [vp.width, vp.height],
            flags,
            iso_refine_steps: s.iso_refine_steps,
            max_samples,
            max_leaves,
            ambient: s.shading.ambient,
            diffuse: s.shading.diffuse,
            specular: s.shading.specular,
            shininess: s.shading.shininess,
            clip_min: s.clip.min,
            clip_pad_a: 0.0,
            clip_max: s.clip.max,
            clip_pad_b: 0.0,
            window_lo: 0.0,
            window_hi: 1.0,
            color_map: 0,
            slab_mode: 0,
            slab_samples: 1,
            slab_dt: 0.0,
            map_pad_a: 0.0,
            map_pad_b: 0.0,
        }
    }
}

/// The per-viewport outputs of the ray-cast pass.
#[derive(Debug)]
pub(crate) struct Outputs {
    pub(crate) size: [u32; 2],
    pub(crate) color: wgpu::TextureView,
    pub(crate) depth: wgpu::TextureView,
    /// The depth output (`COPY_SRC`: picks read it back).
    pub(crate) depth_tex: wgpu::Texture,
    pub(crate) samples: wgpu::Texture,
    samples_view: wgpu::TextureView,
    /// Changes whenever the outputs are recreated (bind groups holding them follow).
    pub(crate) generation: u64,
}

/// Owner of group 0: the frame uniform buffer, the outputs, a stand-in host
/// depth, and the bind group over them.
#[derive(Debug)]
pub(crate) struct FrameState {
    layout: wgpu::BindGroupLayout,
    uniform: Uniform<FrameUniforms>,
    no_host_depth: wgpu::TextureView,
    outputs: Option<Outputs>,
    generation: u64,
    /// The bind group, the outputs and history generations and the host depth
    /// view it holds.
    bind_group: Option<(wgpu::BindGroup, [u64; 2], Option<wgpu::TextureView>)>,
    /// The prediction's uniforms (binding 6).
    predict_uniform: Uniform<PredictUniforms>,
    /// The prediction history (binding 5), while iso frames predict.
    history: Option<History>,
    /// Bound at binding 5 without a history.
    no_history: wgpu::Buffer,
    history_generation: u64,
    /// The reprojection pass, made on first use.
    reprojector: Option<Reprojector>,
}

/// What the prediction did in a frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PredictionFrame {
    /// The history was cleared this frame (first frame, or a change of size,
    /// isovalue, volume, volume frame, projection, step, host depth or the
    /// prediction's settings): every pixel takes the full traversal.
    pub invalidated: bool,
    /// A full-refresh frame (every alpha frames).
    pub refresh: bool,
    /// Last frame's hits were warped into this view (reprojection).
    pub reprojected: bool,
    /// Frames since the history was cleared.
    pub frames: u64,
}

fn storage_texture_entry(binding: u32, format: wgpu::TextureFormat) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::StorageTexture {
            access: wgpu::StorageTextureAccess::WriteOnly,
            format,
            view_dimension: wgpu::TextureViewDimension::D2,
        },
        count: None,
    }
}

/// Group 0's layout: uniforms (0), host depth (1), outputs (2, 3, 4), the
/// prediction history (5) and its uniforms (6).
pub(crate) fn layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    vec![
        gpu::uniform_entry::<FrameUniforms>(0),
        wgpu::BindGroupLayoutEntry {
            binding: 1,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Depth,
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        },
        storage_texture_entry(2, OUTPUT_FORMATS[0]),
        storage_texture_entry(3, OUTPUT_FORMATS[1]),
        storage_texture_entry(4, OUTPUT_FORMATS[2]),
        gpu::storage_entry(5, false),
        wgpu::BindGroupLayoutEntry {
            binding: 6,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: wgpu::BufferSize::new(
                    std::mem::size_of::<PredictUniforms>() as u64
                ),
            },
            count: None,
        },
    ]
}

/// The output formats (bindings 2, 3, 4 of group 0).
pub(crate) const OUTPUT_FORMATS: [wgpu::TextureFormat; 3] = [
    wgpu::TextureFormat::Rgba16Float,
    wgpu::TextureFormat::R32Float,
    wgpu::TextureFormat::R32Uint,
];

impl FrameState {
    pub(crate) fn new(device: &wgpu::Device) -> Result<FrameState, RenderError> {
        let limits = device.limits();
        gpu::need(
            "max_storage_textures_per_shader_stage",
            OUTPUT_FORMATS.len() as u64,
            limits.max_storage_textures_per_shader_stage as u64,
        )?;
        let layout = gpu::scoped(device, "brickray-render frame layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render frame"),
                entries: &layout_entries(),
            })
        })?;
        let no_host_depth = gpu::texture(
            device,
            &wgpu::TextureDescriptor {
                label: Some("brickray-render no host depth"),
                size: wgpu::Extent3d {
                    width: 1,
                    height: 1,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Depth32Float,
                usage: wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            },
        )?
        .create_view(&Default::default());
        let no_history = gpu::storage_buffer(device, "brickray-render no prediction history", 16)?;
        Ok(FrameState {
            layout,
            uniform: Uniform::new(device, "brickray-render frame uniforms")?,
            no_host_depth,
            outputs: None,
            generation: 0,
            bind_group: None,
            predict_uniform: Uniform::new(device, "brickray-render prediction uniforms")?,
            history: None,
            no_history,
            history_generation: 0,
            reprojector: None,
        })
    }

    pub(crate) fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    /// The outputs of the last prepared frame.
    pub(crate) fn outputs(&self) -> Option<&Outputs> {
        self.outputs.as_ref()
    }

    /// The prediction history, while iso frames predict.
    pub(crate) fn history(&self) -> Option<&History> {
        self.history.as_ref()
    }

    /// Drops the prediction history (a new volume: the next frame clears it).
    pub(crate) fn drop_history(&mut self) {
        self.history = None;
    }

    /// Advances the prediction history for this frame: `predict` is the
    /// settings and the volume's identity when this frame predicts. Clears the
    /// history (recording the clear into `encoder`) when what it was computed
    /// for changed, else swaps its halves. Returns the bytes written.
    fn update_prediction(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        desc: &FrameDesc<'_>,
        predict: Option<(Prediction, u64)>,
    ) -> Result<(u64, Option<PredictionFrame>), RenderError> {
        let key = predict.and_then(|(p, volume)| HistoryKey::new(desc, volume, p));
        let Some(key) = key else {
            self.history = None;
            return Ok((0, None));
        };
        let pixels = desc.viewport.width * desc.viewport.height;
        if self.history.as_ref().is_none_or(|h| h.pixels != pixels) {
            self.history = None;
            self.history = Some(History::new(device, pixels)?);
            self.history_generation += 1;
        }
        let h = self.history.as_mut().expect("made above");
        let invalidated = h.key != Some(key);
        if invalidated {
            encoder.clear_buffer(&h.buffer, 0, None);
            h.frames = 0;
            h.key = Some(key);
        } else {
            h.parity ^= 1;
            h.frames += 1;
        }
        let p = key.settings;
        let refresh = h.frames.is_multiple_of(p.alpha as u64);
        let n = h.pixels;
        let basis = Basis::of(desc);
        let prev_basis = h.basis.replace(basis);
        let mut written = 0;
        // Reprojection: warp last frame's entries (the half this frame would
        // read) into the fourth region, which this frame reads instead.
        let reproject = match prev_basis {
            Some(prev) if p.reproject && !invalidated && !refresh => Some(prev),
            _ => None,
        };
        if let Some(prev) = reproject {
            if self.reprojector.is_none() {
                self.reprojector = Some(Reprojector::new(device)?);
            }
            let h = self.history.as_ref().expect("made above");
            let u = ReprojectUniforms::new(
                prev,
                basis,
                [desc.viewport.width, desc.viewport.height],
                h.parity * n,
                3 * n,
            );
            written += self.reprojector.as_mut().expect("made above").record(
                device,
                queue,
                encoder,
                h,
                self.history_generation,
                u,
            )?;
        }
        let h = self.history.as_ref().expect("made above");
        // The sparse step over the full one, as bisection steps.
        let ratio = 1.0 / (p.kappa as f64 * desc.settings.step_factor as f64);
        let sparse_refine = ratio.log2().ceil().clamp(0.0, 16.0) as u32;
        written += self.predict_uniform.write(
            queue,
            PredictUniforms {
                read_off: if reproject.is_some() {
                    3 * n
                } else {
                    h.parity * n
                },
                write_off: (1 - h.parity) * n,
                class_off: 2 * n,
                refresh: refresh as u32,
                local_steps: p.local_steps,
                sparse_refine,
                sparse_dt: (desc.frame.voxel_world as f64 / p.kappa as f64) as f32,
                reprojected: reproject.is_some() as u32,
            },
        );
        Ok((
            written,
            Some(PredictionFrame {
                invalidated,
                refresh,
                reprojected: reproject.is_some(),
                frames: h.frames,
            }),
        ))
    }

    /// Sizes the outputs to the viewport, writes the uniforms (when changed),
    /// advances the prediction history (see `update_prediction`) and rebuilds
    /// the bind group when the outputs, the history or the host depth view
    /// changed. Returns the bytes written.
    pub(crate) fn update(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        desc: &FrameDesc<'_>,
        uniforms: FrameUniforms,
        predict: Option<(Prediction, u64)>,
    ) -> Result<(u64, Option<PredictionFrame>), PrepareError> {
        self.ensure_outputs(device, desc.viewport)?;
        let mut written = self.uniform.write(queue, uniforms);
        let (w, predicted) = self.update_prediction(device, queue, encoder, desc, predict)?;
        written += w;
        let host = desc.host_depth.cloned();
        let outputs = self.outputs.as_ref().expect("ensured above");
        let generations = [
            outputs.generation,
            self.history.as_ref().map_or(0, |_| self.history_generation),
        ];
        let stale = self
            .bind_group
            .as_ref()
            .is_none_or(|(_, g, h)| *g != generations || *h != host);
        if stale {
            let history = self
                .history
                .as_ref()
                .map_or(&self.no_history, |h| &h.buffer);
            let depth = host.as_ref().unwrap_or(&self.no_host_depth);
            let view = |v| wgpu::BindingResource::TextureView(v);
            let bg = gpu::scoped(device, "brickray-render frame bind group", || {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("brickray-render frame"),
                    layout: &self.layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: self.uniform.buffer.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: view(depth),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: view(&outputs.color),
                        },
                        wgpu::BindGroupEntry {
                            binding: 3,
                            resource: view(&outputs.depth),
                        },
                        wgpu::BindGroupEntry {
                            binding: 4,
                            resource: view(&outputs.samples_view),
                        },
                        wgpu::BindGroupEntry {
                            binding: 5,
                            resource: history.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 6,
                            resource: self.predict_uniform.buffer.as_entire_binding(),
                        },
                    ],
                })
            })?;
            self.bind_group = Some((bg, generations, host));
        }
        Ok((written, predicted))
    }

    pub(crate) fn bind_group(&self) -> Option<&wgpu::BindGroup> {
        self.bind_group.as_ref().map(|(bg, _, _)| bg)
    }

    fn ensure_outputs(&mut self, device: &wgpu::Device, vp: Viewport) -> Result<(), RenderError> {
        let size = [vp.width, vp.height];
        if self.outputs.as_ref().is_some_and(|o| o.size == size) {
            return Ok(());
        }
        // Free the old outputs before allocating new ones.
        self.outputs = None;
        self.bind_group = None;
        let make = |label, format, extra| {
            gpu::texture(
                device,
                &wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d {
                        width: vp.width,
                        height: vp.height,
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage: wgpu::TextureUsages::STORAGE_BINDING
                        | wgpu::TextureUsages::TEXTURE_BINDING
                        | extra,
                    view_formats: &[],
                },
            )
        };
        let none = wgpu::TextureUsages::empty();
        let color = make("brickray-render ray colour", OUTPUT_FORMATS[0], none)?;
        let depth = make(
            "brickray-render ray depth",
            OUTPUT_FORMATS[1],
            wgpu::TextureUsages::COPY_SRC,
        )?;
        let samples = make(
            "brickray-render ray samples",
            OUTPUT_FORMATS[2],
            wgpu::TextureUsages::COPY_SRC,
        )?;
        self.generation += 1;
        self.outputs = Some(Outputs {
            size,
            color: color.create_view(&Default::default()),
            depth: depth.create_view(&Default::default()),
            depth_tex: depth,
            samples_view: samples.create_view(&Default::default()),
            samples,
            generation: self.generation,
        });
        Ok(())
    }
}

/// Checks the host's depth view against what group 0 binds: a single-sampled,
/// bindable depth texture covering the viewport.
pub(crate) fn check_host_depth(
    view: &wgpu::TextureView,
    vp: Viewport,
) -> Result<(), HostDepthError> {
    let t = view.texture();
    if !t.usage().contains(wgpu::TextureUsages::TEXTURE_BINDING) {
        return Err(HostDepthError::NotBindable(t.usage()));
    }
    if !t.format().has_depth_aspect() {
        return Err(HostDepthError::NotDepth(t.format()));
    }
    if t.sample_count() != 1 {
        return Err(HostDepthError::Multisampled(t.sample_count()));
    }
    let needed = [
        vp.x.saturating_add(vp.width),
        vp.y.saturating_add(vp.height),
    ];
    if t.width() < needed[0] || t.height() < needed[1] {
        return Err(HostDepthError::TooSmall {
            size: [t.width(), t.height()],
            needed,
        });
    }
    Ok(())
}
