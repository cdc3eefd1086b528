//! Occlusion-query feedback (Gobbetti et al. 2008, section 6; docs/visibility.md),
//! the GPU half (the planner, `brickray_cache::Streamer`, schedules the
//! queries and projects the boxes).
//!
//! The out-of-core kernel writes, per pixel, the clip depth of the last sample
//! its ray visited into an R32Float texture (`feedback.wgsl`). After the ray
//! cast this records one depth-only render pass (`occlusion.wgsl`): a
//! fullscreen triangle copies that depth into a depth attachment, then the
//! boxes of the leaves the plan's [`QueryBatch`] holds are drawn against it,
//! depth test on and writes off, each in its own occlusion query. The query
//! results are resolved and copied, with a frame stamp, into a ring of
//! read-back buffers mapped asynchronously (`readback.rs`), as the usage
//! counters are: nothing here polls or waits.
//!
//! wgpu records the ray cast as one compute dispatch and the queries as a
//! later render pass of the same submission; it gives no control over their
//! overlap on the GPU. The tile list is computed (and reported) but the ray
//! cast is not split into tiles: the paper's ordering hides query latency
//! inside a frame, whereas here the results come back through the read-back
//! ring one or two frames later whatever the order, so splitting the dispatch
//! would only add passes.

use super::readback::ReadbackRing;
use crate::error::RenderError;
use crate::gpu;
use brickray_cache::{QueryBatch, QueryResult, QuerySchedule};
use brickray_core::NodeKey;

/// Read-back buffers in flight at most.
const RING: usize = 4;
/// Bytes of one box instance: corner and three edges, `vec4<f32>` each.
const BOX_BYTES: u64 = 64;

/// The shader (validated with the others in `shaders/tests.rs`).
pub(crate) const WGSL: &str = include_str!("../../shaders/occlusion.wgsl");

/// `struct OcclusionUniforms` of occlusion.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct OcclusionUniforms {
    pub(crate) view_proj: [[f32; 4]; 4],
}

/// The layout of occlusion.wgsl's group 0: the stop depth (sampled, not
/// filterable) and the uniforms.
pub(crate) fn layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    vec![
        wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        },
        wgpu::BindGroupLayoutEntry {
            binding: 1,
            visibility: wgpu::ShaderStages::VERTEX,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        },
    ]
}

/// Counters of the occlusion-query path.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OcclusionStats {
    /// Queries issued in the last frame.
    pub queries: u32,
    /// Frames the scheduler's rotation takes to query every on-screen leaf.
    pub period: u32,
    /// Tiles of the last frame's screen subdivision.
    pub tiles: u32,
    /// Leaves whose box reaches behind the near plane (visible, not queried).
    pub near_visible: u32,
    /// Frames whose results were read back and applied.
    pub frames_applied: u64,
    /// Read-backs discarded (stamp mismatch or failed mapping).
    pub frames_discarded: u64,
    /// Frames that found no free ring entry (no queries recorded).
    pub frames_skipped: u64,
}

/// The viewport-sized textures.
struct Targets {
    size: [u32; 2],
    stop: wgpu::Texture,
    stop_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    bind_group: wgpu::BindGroup,
}

pub(crate) struct OcclusionFeedback {
    budget: u32,
    targets: Targets,
    uniforms: wgpu::Buffer,
    group_layout: wgpu::BindGroupLayout,
    fill: wgpu::RenderPipeline,
    boxes_less: wgpu::RenderPipeline,
    boxes_greater: wgpu::RenderPipeline,
    box_buffer: wgpu::Buffer,
    queries: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    /// Each entry remembers the leaves its frame queried.
    ring: ReadbackRing<Vec<NodeKey>>,
    /// This frame's queried leaves (recorded after the pass).
    pending: Vec<NodeKey>,
    reversed: bool,
    schedule: QuerySchedule,
}

const STOP_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

impl OcclusionFeedback {
    pub(crate) fn new(
        device: &wgpu::Device,
        budget: u32,
    ) -> Result<OcclusionFeedback, RenderError> {
        let l = device.limits();
        let budget = budget.clamp(1, wgpu::QUERY_SET_MAX_QUERIES);
        gpu::need("max_vertex_buffers", 1, l.max_vertex_buffers as u64)?;
        gpu::need("max_vertex_attributes", 4, l.max_vertex_attributes as u64)?;
        let group_layout = gpu::scoped(device, "brickray-render occlusion layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render occlusion"),
                entries: &layout_entries(),
            })
        })?;
        let uniforms = gpu::buffer(
            device,
            "brickray-render occlusion uniforms",
            std::mem::size_of::<OcclusionUniforms>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )?;
        let module = gpu::scoped(device, "brickray-render occlusion shader", || {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("brickray-render occlusion"),
                source: wgpu::ShaderSource::Wgsl(WGSL.into()),
            })
        })?;
        let pl = gpu::scoped(device, "brickray-render occlusion pipeline layout", || {
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("brickray-render occlusion"),
                bind_group_layouts: &[Some(&group_layout)],
                immediate_size: 0,
            })
        })?;
        let attrs = wgpu::vertex_attr_array![0 => Float32x4, 1 => Float32x4, 2 => Float32x4, 3 => Float32x4];
        let pipeline = |label: &'static str,
                        vs: &str,
                        fs: Option<&str>,
                        compare: wgpu::CompareFunction,
                        write: bool,
                        boxes: bool| {
            let buffers = [Some(wgpu::VertexBufferLayout {
                array_stride: BOX_BYTES,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &attrs,
            })];
            gpu::scoped(device, label, || {
                device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some(label),
                    layout: Some(&pl),
                    vertex: wgpu::VertexState {
                        module: &module,
                        entry_point: Some(vs),
                        compilation_options: Default::default(),
                        buffers: if boxes { &buffers } else { &[] },
                    },
                    primitive: wgpu::PrimitiveState::default(),
                    depth_stencil: Some(wgpu::DepthStencilState {
                        format: DEPTH_FORMAT,
                        depth_write_enabled: Some(write),
                        depth_compare: Some(compare),
                        stencil: Default::default(),
                        bias: Default::default(),
                    }),
                    multisample: Default::default(),
                    fragment: fs.map(|fs| wgpu::FragmentState {
                        module: &module,
                        entry_point: Some(fs),
                        compilation_options: Default::default(),
                        targets: &[],
                    }),
                    multiview_mask: None,
                    cache: None,
                })
            })
        };
        let fill = pipeline(
            "brickray-render occlusion fill",
            "fill_vs",
            Some("fill_fs"),
            wgpu::CompareFunction::Always,
            true,
            false,
        )?;
        let boxes_less = pipeline(
            "brickray-render occlusion boxes",
            "box_vs",
            None,
            wgpu::CompareFunction::LessEqual,
            false,
            true,
        )?;
        let boxes_greater = pipeline(
            "brickray-render occlusion boxes (reversed-Z)",
            "box_vs",
            None,
            wgpu::CompareFunction::GreaterEqual,
            false,
            true,
        )?;
        let box_buffer = gpu::buffer(
            device,
            "brickray-render occlusion boxes",
            budget as u64 * BOX_BYTES,
            wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
        )?;
        let queries = gpu::scoped(device, "brickray-render occlusion queries", || {
            device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("brickray-render occlusion"),
                ty: wgpu::QueryType::Occlusion,
                count: budget,
            })
        })?;
        let resolve = gpu::buffer(
            device,
            "brickray-render occlusion resolve",
            budget as u64 * 8,
            wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
        )?;
        let ring = ReadbackRing::new(
            device,
            "brickray-render occlusion read-back",
            RING,
            budget as u64 * 8,
        )?;
        let targets = Self::targets(device, &group_layout, &uniforms, [1, 1])?;
        Ok(OcclusionFeedback {
            budget,
            targets,
            uniforms,
            group_layout,
            fill,
            boxes_less,
            boxes_greater,
            box_buffer,
            queries,
            resolve,
            ring,
            pending: Vec::new(),
            reversed: false,
            schedule: QuerySchedule::default(),
        })
    }

    fn targets(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        uniforms: &wgpu::Buffer,
        size: [u32; 2],
    ) -> Result<Targets, RenderError> {
        let extent = wgpu::Extent3d {
            width: size[0],
            height: size[1],
            depth_or_array_layers: 1,
        };
        let tex = |label: &'static str, format, usage| {
            gpu::texture(
                device,
                &wgpu::TextureDescriptor {
                    label: Some(label),
                    size: extent,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                },
            )
        };
        let stop = tex(
            "brickray-render stop depth",
            STOP_FORMAT,
            wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::TEXTURE_BINDING,
        )?;
        let depth = tex(
            "brickray-render occlusion depth",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        )?;
        let stop_view = stop.create_view(&Default::default());
        let depth_view = depth.create_view(&Default::default());
        let bind_group = gpu::scoped(device, "brickray-render occlusion bind group", || {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("brickray-render occlusion"),
                layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(&stop_view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: uniforms.as_entire_binding(),
                    },
                ],
            })
        })?;
        Ok(Targets {
            size,
            stop,
            stop_view,
            depth_view,
            bind_group,
        })
    }

    /// The stop-depth texture the kernel writes (group 2, binding 7).
    pub(crate) fn stop_view(&self) -> &wgpu::TextureView {
        &self.targets.stop_view
    }

    /// Resizes the viewport-sized textures; true when they were recreated (the
    /// kernel's group 2 must be rebuilt).
    pub(crate) fn resize(
        &mut self,
        device: &wgpu::Device,
        size: [u32; 2],
    ) -> Result<bool, RenderError> {
        if self.targets.size == size {
            return Ok(false);
        }
        self.targets = Self::targets(device, &self.group_layout, &self.uniforms, size)?;
        let _ = &self.targets.stop;
        Ok(true)
    }

    /// The schedule of the last frame and the ring's counters.
    pub(crate) fn stats(&self) -> OcclusionStats {
        let r = self.ring.stats;
        OcclusionStats {
            queries: self.schedule.queries,
            period: self.schedule.period,
            tiles: self.schedule.tiles,
            near_visible: self.schedule.near_visible,
            frames_applied: r.applied,
            frames_discarded: r.discarded,
            frames_skipped: r.skipped,
        }
    }

    /// Results read back since the last call. Never waits.
    pub(crate) fn poll(&mut self, frame: u64) -> Vec<QueryResult> {
        self.ring
            .poll(frame, |entry_frame, keys, payload| {
                let r: &[u64] = bytemuck::cast_slice(payload);
                keys.iter()
                    .enumerate()
                    .map(|(i, &key)| QueryResult {
                        frame: entry_frame,
                        key,
                        samples: r.get(i).copied().unwrap_or(0).min(u32::MAX as u64) as u32,
                    })
                    .collect::<Vec<_>>()
            })
            .into_iter()
            .flat_map(|(_, r)| r)
            .collect()
    }

    /// Writes this frame's boxes (the plan's batch for this view).
    pub(crate) fn write(&mut self, queue: &wgpu::Queue, batch: &QueryBatch) {
        let n = batch.keys.len().min(self.budget as usize);
        self.reversed = batch.reversed;
        self.pending = batch.keys[..n].to_vec();
        self.schedule = batch.schedule;
        if n > 0 {
            queue.write_buffer(&self.box_buffer, 0, bytemuck::cast_slice(&batch.boxes[..n]));
            queue.write_buffer(
                &self.uniforms,
                0,
                bytemuck::bytes_of(&OcclusionUniforms {
                    view_proj: batch.view_proj,
                }),
            );
        }
    }

    /// Records the depth fill and this frame's queries after the ray cast,
    /// then the copy of their results into a free ring entry.
    pub(crate) fn record(
        &mut self,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        frame: u64,
    ) {
        if self.pending.is_empty() {
            return;
        }
        let n = self.pending.len() as u32;
        let far = if self.reversed { 0.0 } else { 1.0 };
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("brickray-render occlusion queries"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.targets.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(far),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: Some(&self.queries),
                multiview_mask: None,
            });
            pass.set_bind_group(0, &self.targets.bind_group, &[]);
            pass.set_pipeline(&self.fill);
            pass.draw(0..3, 0..1);
            pass.set_pipeline(if self.reversed {
                &self.boxes_greater
            } else {
                &self.boxes_less
            });
            pass.set_vertex_buffer(0, self.box_buffer.slice(..));
            for i in 0..n {
                pass.begin_occlusion_query(i);
                pass.draw(0..36, i..i + 1);
                pass.end_occlusion_query();
            }
        }
        encoder.resolve_query_set(&self.queries, 0..n, &self.resolve, 0);
        let resolve = &self.resolve;
        let keys = std::mem::take(&mut self.pending);
        self.ring
            .record(queue, encoder, frame, keys, |enc, dst, at| {
                enc.copy_buffer_to_buffer(resolve, 0, dst, at, n as u64 * 8);
            });
    }
}
