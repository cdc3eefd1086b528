//! The multi-channel in-core backend: 1 to 4 intensity channels packed in
//! one 3D texture (RG or RGBA of the dtype's format, filtered by the
//! hardware), each channel's macro-cell ranges, and the channels'
//! classification (their corrected TF tables stacked in one texture, their
//! entries, visibility and isovalues), all in group 2 of
//! `shaders/channels.wgsl`.

use super::VolumeBackend;
use super::incore::{CELL, SKIP_CAP};
use crate::encoding::{self, SampleEncoding, U8Filtering};
use crate::error::RenderError;
use crate::gpu::{self, GrowBuffer, Uniform};
use crate::group2::{INCORE_STORAGE_BUFFERS, check_stage_limits, volume_sampler};
use crate::kernels::KernelKind;
use brickray_core::channels::{self, ChannelStyle, ChannelVolume};
use brickray_core::{MacroCellGrid, RenderMode, TransferFunction};

/// Storage buffers of this group 2: the in-core ones and the TF entries.
pub(crate) const STORAGE_BUFFERS: u32 = INCORE_STORAGE_BUFFERS + 1;
/// The stacked corrected tables' binding.
const TABLE_BINDING: u32 = 5;
/// The TF entries' binding.
const ENTRIES_BINDING: u32 = 6;

/// `struct ChannelParams` of channels.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct ChannelParams {
    pub(crate) dims: [f32; 3],
    pub(crate) channels: u32,
    pub(crate) cells: [u32; 3],
    pub(crate) cell_size: u32,
    pub(crate) scale: [f32; 4],
    pub(crate) offset: [f32; 4],
    pub(crate) tf_count: [f32; 4],
    pub(crate) tf_offset: [u32; 4],
    pub(crate) table_rows: f32,
    pub(crate) table_width: f32,
    pub(crate) pad0: f32,
    pub(crate) pad1: f32,
}

/// What the skip distances were computed for.
#[derive(Debug, Clone, Copy, PartialEq)]
enum SkipKey {
    Dvr(u64),
    Iso(u64),
}

/// What the stacked tables were built for.
#[derive(Debug, Clone, Copy, PartialEq)]
struct TableKey {
    step_factor: f32,
    generation: u64,
    rows: u32,
}

/// The layout of this group 2: the in-core entries, the stacked tables and
/// the TF entries.
pub(crate) fn layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    let mut e = crate::group2::volume_layout_entries(INCORE_STORAGE_BUFFERS);
    e.push(wgpu::BindGroupLayoutEntry {
        binding: TABLE_BINDING,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: true },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    });
    e.push(gpu::storage_entry(ENTRIES_BINDING, true));
    e
}

/// A multi-channel volume resident on the GPU.
#[derive(Debug)]
pub(crate) struct Channels {
    layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    format: wgpu::TextureFormat,
    bytes: u64,
    count: usize,
    params: Uniform<ChannelParams>,
    base: ChannelParams,
    view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    cell_ranges: wgpu::Buffer,
    skip: wgpu::Buffer,
    class: ClassTables,
    /// Each channel's macro-cell grid (its ranges decide skipping).
    grids: Vec<MacroCellGrid>,
    skip_key: Option<SkipKey>,
}

impl Channels {
    /// Packs and uploads the channels (in slabs of at most 64 MiB) and their
    /// macro-cell ranges.
    pub(crate) fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        vol: &ChannelVolume,
        u8: U8Filtering,
    ) -> Result<Channels, RenderError> {
        check_stage_limits(device, STORAGE_BUFFERS)?;
        gpu::need(
            "max_sampled_textures_per_shader_stage",
            crate::group2::CHANNEL_SAMPLED_TEXTURES as u64,
            device.limits().max_sampled_textures_per_shader_stage as u64,
        )?;
        let dims = vol.dims();
        let limit = device.limits().max_texture_dimension_3d;
        if dims.iter().any(|&d| d > limit) {
            return Err(RenderError::VolumeTooLarge { dims, limit });
        }
        for v in vol.channels() {
            crate::check_value_range(v.desc().value_range)?;
        }
        let caps = encoding::caps(device);
        let encs: Vec<SampleEncoding> = vol
            .channels()
            .iter()
            .map(|v| SampleEncoding::for_volume(v.desc(), caps, u8))
            .collect();
        let count = vol.len();
        let lanes = channels::texel_lanes(count);
        let tb = encs[0].texel_bytes();
        let format = encoding::wgpu_format_lanes(encs[0].format, lanes);
        let slice = dims[0] as usize * dims[1] as usize * vol.dtype().size();
        let (texture, bytes) = gpu::slab_texture(
            device,
            queue,
            dims,
            format,
            tb * lanes as u32,
            "brickray-render channels",
            |z0, z1| {
                let parts: Vec<_> = vol
                    .channels()
                    .iter()
                    .zip(&encs)
                    .map(|(v, e)| e.encode(&v.data().as_bytes()[z0 * slice..z1 * slice]))
                    .collect();
                let refs: Vec<&[u8]> = parts.iter().map(|p| p.as_ref()).collect();
                channels::interleave(&refs, tb as usize, lanes).into()
            },
        )?;
        let grids: Vec<MacroCellGrid> = vol
            .channels()
            .iter()
            .map(|v| MacroCellGrid::build(v, CELL))
            .collect();
        let cells = grids[0].ranges.len();
        let mut ranges = Vec::with_capacity(cells * count);
        for i in 0..cells {
            ranges.extend(grids.iter().map(|g| g.ranges[i]));
        }
        let ranges: &[u8] = bytemuck::cast_slice(&ranges);
        let cell_ranges = gpu::storage_buffer(
            device,
            "brickray-render channel macro-cell ranges",
            ranges.len() as u64,
        )?;
        queue.write_buffer(&cell_ranges, 0, ranges);
        let skip = gpu::storage_buffer(
            device,
            "brickray-render channel skip distances",
            cells as u64 * 4,
        )?;
        let lane = |f: &dyn Fn(&SampleEncoding) -> f32| -> [f32; 4] {
            std::array::from_fn(|c| encs.get(c).map_or(0.0, f))
        };
        let base = ChannelParams {
            dims: dims.map(|d| d as f32),
            channels: count as u32,
            cells: grids[0].dims,
            cell_size: CELL,
            scale: lane(&|e| e.scale),
            offset: lane(&|e| e.offset),
            tf_count: [2.0; 4],
            tf_offset: [0; 4],
            table_rows: 1.0,
            table_width: 2.0,
            pad0: 0.0,
            pad1: 0.0,
        };
        let mut params = Uniform::<ChannelParams>::new(device, "brickray-render channel params")?;
        params.write(queue, base);
        let sampler = volume_sampler(device, false)?;
        let layout = gpu::scoped(device, "brickray-render channels layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render channels"),
                entries: &layout_entries(),
            })
        })?;
        let class = ClassTables::new(device, count)?;
        let view = texture.create_view(&Default::default());
        let bind_group = make_bind_group(
            device,
            &layout,
            [&params.buffer, &cell_ranges, &skip, &class.entries.buffer],
            &view,
            &sampler,
            &class.table.1,
        )?;
        Ok(Channels {
            layout,
            bind_group,
            format,
            bytes,
            count,
            params,
            base,
            view,
            sampler,
            cell_ranges,
            skip,
            class,
            grids,
            skip_key: None,
        })
    }

    /// Channels of the volume.
    pub(crate) fn count(&self) -> usize {
        self.count
    }

    /// Keeps the classification current for the frame: the stacked tables
    /// for `step_factor` and `styles` (of `generation`; one row, and
    /// `extra_rows` more for the adaptive step's doublings), the uniforms,
    /// and the skip distances for the mode. Returns the bytes written.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn update(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        mode: RenderMode,
        styles: &[ChannelStyle],
        generation: u64,
        step_factor: f32,
        extra_rows: u32,
    ) -> Result<u64, RenderError> {
        channels::validate_styles(styles, self.count)?;
        let mut written = 0;
        let rows = 1 + extra_rows;
        if let Some((w, layout, rebind)) =
            self.class
                .update(device, queue, styles, generation, step_factor, rows)?
        {
            let mut p = self.base;
            p.tf_offset = layout.tf_offset;
            p.tf_count = layout.tf_count;
            p.table_width = layout.width;
            p.table_rows = rows as f32;
            written += w + self.params.write(queue, p);
            if rebind {
                self.bind_group = make_bind_group(
                    device,
                    &self.layout,
                    [
                        &self.params.buffer,
                        &self.cell_ranges,
                        &self.skip,
                        &self.class.entries.buffer,
                    ],
                    &self.view,
                    &self.sampler,
                    &self.class.table.1,
                )?;
            }
        }
        let skip = match mode {
            RenderMode::Iso { .. } => SkipKey::Iso(generation),
            RenderMode::Mip => return Ok(written),
            _ => SkipKey::Dvr(generation),
        };
        if self.skip_key != Some(skip) {
            let ranges: Vec<&[[f32; 2]]> = self.grids.iter().map(|g| g.ranges.as_slice()).collect();
            let visible: Vec<bool> = styles.iter().map(|s| s.visible).collect();
            let empty = match skip {
                SkipKey::Iso(_) => {
                    channels::cells_empty(&ranges, &visible, |c, r| r[1] < styles[c].isovalue)
                }
                SkipKey::Dvr(_) => channels::cells_empty(&ranges, &visible, |c, r| {
                    styles[c].tf.is_transparent(r[0], r[1])
                }),
            };
            let d = brickray_core::empty_distance(self.grids[0].dims, &empty, SKIP_CAP);
            let bytes: &[u8] = bytemuck::cast_slice(&d);
            queue.write_buffer(&self.skip, 0, bytes);
            written += bytes.len() as u64;
            self.skip_key = Some(skip);
        }
        Ok(written)
    }
}

/// Rows of the classification buffer before the TF entries
/// (`CLASS_HEADER` in channels.wgsl).
pub(crate) const CLASS_HEADER: usize = 7;

/// The classification buffer's header: visibility (1 or 0 per lane),
/// isovalues, each channel's isosurface colour, and the slice gains
/// (`channels::slice_gain`; lanes and rows past the channels zero). In storage, not uniforms: lavapipe inlines uniform
/// values that steer branches, and crashed compiling the kernel with these.
fn class_header(styles: &[ChannelStyle]) -> Vec<[f32; 4]> {
    let mut h = vec![[0.0f32; 4]; CLASS_HEADER];
    for (c, s) in styles.iter().enumerate().take(4) {
        h[0][c] = if s.visible { 1.0 } else { 0.0 };
        h[1][c] = s.isovalue;
        let [r, g, b] = s.iso_color();
        h[2 + c] = [r, g, b, 1.0];
        h[6][c] = channels::slice_gain(&s.tf) as f32;
    }
    h
}

/// Where a channel's classification lies in the buffers [`ClassTables`]
/// wrote (the `chan` uniform's fields).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ClassLayout {
    pub(crate) tf_count: [f32; 4],
    pub(crate) tf_offset: [u32; 4],
    /// Each channel's opacity prefix sums (`tf_count + 1` rows, the sum in
    /// x), after every channel's entries.
    pub(crate) prefix_offset: [u32; 4],
    /// Columns of the stacked tables.
    pub(crate) width: f32,
}

/// The channels' classification on the GPU, shared by both multi-channel
/// kernels (`channel_class.wgsl`): their corrected tables stacked in one
/// texture (`rows` per channel: one per step length), and one storage buffer
/// of the header ([`class_header`]), each channel's TF entries and its
/// opacity prefix sums. Rebuilt only when the styles, the step or the rows
/// change.
#[derive(Debug)]
pub(crate) struct ClassTables {
    pub(crate) table: (wgpu::Texture, wgpu::TextureView),
    pub(crate) entries: GrowBuffer,
    key: Option<TableKey>,
}

impl ClassTables {
    pub(crate) fn new(device: &wgpu::Device, channels: usize) -> Result<ClassTables, RenderError> {
        Ok(ClassTables {
            table: table_texture(device, 2, channels as u32)?,
            entries: GrowBuffer::new(device, "brickray-render channel tf entries", 16)?,
            key: None,
        })
    }

    /// Writes the tables and entries of `styles` (of `generation`) for
    /// `step_factor` with `rows` rows per channel, when they changed:
    /// `Some((bytes written, layout, rebind))`, `rebind` when a bound
    /// object was recreated; `None` when nothing changed.
    pub(crate) fn update(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        styles: &[ChannelStyle],
        generation: u64,
        step_factor: f32,
        rows: u32,
    ) -> Result<Option<(u64, ClassLayout, bool)>, RenderError> {
        for s in styles {
            if s.tf.len() > TransferFunction::MAX_ENTRIES {
                return Err(brickray_core::TfError::TooMany {
                    len: s.tf.len(),
                    max: TransferFunction::MAX_ENTRIES,
                }
                .into());
            }
        }
        let key = TableKey {
            step_factor,
            generation,
            rows,
        };
        if self.key == Some(key) {
            return Ok(None);
        }
        let max_width = device.limits().max_texture_dimension_2d;
        let width = styles
            .iter()
            .map(|s| s.tf.table_width(max_width))
            .max()
            .unwrap_or(2);
        let mut texels = Vec::with_capacity((width * rows) as usize * styles.len());
        for s in styles {
            texels.extend(
                s.tf.corrected_table_of_width(step_factor, rows, width)
                    .texels,
            );
        }
        let size = wgpu::Extent3d {
            width,
            height: styles.len() as u32 * rows,
            depth_or_array_layers: 1,
        };
        let mut rebind = false;
        if self.table.0.size() != size {
            self.table = table_texture(device, width, size.height)?;
            rebind = true;
        }
        let mut written = crate::tf::write_rgba16f(queue, &self.table.0, &texels, size);
        let mut all = class_header(styles);
        let mut layout = ClassLayout {
            tf_count: [2.0; 4],
            tf_offset: [0; 4],
            prefix_offset: [0; 4],
            width: width as f32,
        };
        for (c, s) in styles.iter().enumerate() {
            layout.tf_offset[c] = all.len() as u32;
            layout.tf_count[c] = s.tf.len() as f32;
            all.extend_from_slice(s.tf.entries());
        }
        for (c, s) in styles.iter().enumerate() {
            layout.prefix_offset[c] = all.len() as u32;
            all.extend(s.tf.prefix().iter().map(|&p| [p as f32, 0.0, 0.0, 0.0]));
        }
        let (w, grew) = self
            .entries
            .write(device, queue, bytemuck::cast_slice(&all))?;
        written += w;
        self.key = Some(key);
        Ok(Some((written, layout, rebind || grew)))
    }
}

/// The stacked tables' texture: `width` columns, one row per channel.
fn table_texture(
    device: &wgpu::Device,
    width: u32,
    rows: u32,
) -> Result<(wgpu::Texture, wgpu::TextureView), RenderError> {
    let tex = crate::tf::table_texture(
        device,
        "brickray-render channel tf tables",
        wgpu::Extent3d {
            width,
            height: rows.max(1),
            depth_or_array_layers: 1,
        },
    )?;
    let view = tex.create_view(&Default::default());
    Ok((tex, view))
}

/// Group 2 over the uniform, ranges, skip distances and entries (in that
/// order), the volume, its sampler and the stacked tables.
fn make_bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    buffers: [&wgpu::Buffer; 4],
    volume: &wgpu::TextureView,
    sampler: &wgpu::Sampler,
    table: &wgpu::TextureView,
) -> Result<wgpu::BindGroup, RenderError> {
    let [params, ranges, skip, entries] = buffers;
    gpu::scoped(device, "brickray-render channels bind group", || {
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("brickray-render channels"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(volume),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: ranges.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: skip.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: TABLE_BINDING,
                    resource: wgpu::BindingResource::TextureView(table),
                },
                wgpu::BindGroupEntry {
                    binding: ENTRIES_BINDING,
                    resource: entries.as_entire_binding(),
                },
            ],
        })
    })
}

impl VolumeBackend for Channels {
    fn kind(&self) -> KernelKind {
        KernelKind::Channels
    }

    fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    fn bind_group(&self) -> &wgpu::BindGroup {
        &self.bind_group
    }

    fn max_leaves(&self) -> u32 {
        0
    }

    fn labels(&self) -> bool {
        false
    }

    fn step_lengths(&self) -> u32 {
        1
    }

    fn wants_redraw(&self) -> bool {
        false
    }

    fn texel_format(&self) -> wgpu::TextureFormat {
        self.format
    }

    fn resident_bytes(&self) -> u64 {
        self.bytes
    }
}
