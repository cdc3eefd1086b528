//! Group 1 of every ray-cast kernel: the transfer function's entries, its
//! opacity prefix sums, and the corrected table (a filtered `Rgba16Float` 2D
//! texture, one row per step length in use: `brickray_core::tf::CorrectedTable`)
//! with its sampler, their sizes, the pre-integrated table (a filtered
//! `Rgba16Float` 2D array, one layer per step length:
//! `brickray_core::tf::PreintTable`; a 1x1 stand-in while pre-integration is
//! off), the spread table (a filtered `Rgba16Float` 2D array, one layer per
//! step length, each the TF convolved by 32 spreads:
//! `brickray_core::tf::SpreadTable::corrected_layers`; a 1x1 stand-in until a
//! volume with spreads is drawn), and the bind group.

use crate::error::RenderError;
use crate::gpu::{self, GrowBuffer, TableTexture, Uniform};
use brickray_core::TransferFunction;
use brickray_core::tf::SPREAD_ROWS;

/// `struct TfInfo` of common.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct TfInfo {
    /// Entries of the TF, as a float.
    pub(crate) count: f32,
    /// Columns of the corrected table, as a float.
    pub(crate) width: f32,
    /// Rows of the corrected table, as a float.
    pub(crate) rows: f32,
    /// Columns (and rows) of a pre-integrated table layer, as a float.
    pub(crate) preint_size: f32,
}

/// Texel format of the corrected table (filterable on every WebGPU device).
pub(crate) const TABLE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;

/// What a corrected table was built for.
#[derive(Debug, Clone, Copy, PartialEq)]
struct TableKey {
    step_factor: f32,
    rows: u32,
}

/// Columns and rows of a pre-integrated table layer.
pub(crate) const PREINT_SIZE: u32 = brickray_core::tf::PREINT_MIN_SIZE;

/// Owner of group 1.
#[derive(Debug)]
pub(crate) struct TfTables {
    layout: wgpu::BindGroupLayout,
    entries: GrowBuffer,
    /// The opacity prefix sums (a `TableTexture`, R32Uint: read per
    /// sub-cell test out of core).
    prefix: TableTexture,
    info: Uniform<TfInfo>,
    sampler: wgpu::Sampler,
    table: Option<(wgpu::Texture, wgpu::TextureView)>,
    /// The pre-integrated table (or the 1x1 stand-in while it is off).
    preint: Option<(wgpu::Texture, wgpu::TextureView)>,
    /// The spread table (or the 1x1 stand-in until one is asked for).
    spread: Option<(wgpu::Texture, wgpu::TextureView)>,
    /// What the spread table was built for (`None`: the stand-in, or stale).
    spread_key: Option<TableKey>,
    table_key: Option<TableKey>,
    /// What the pre-integrated table was built for (`None`: the stand-in, or
    /// stale). Kept while pre-integration is off, so toggling it rebuilds nothing.
    preint_key: Option<TableKey>,
    bind_group: Option<wgpu::BindGroup>,
    current: Option<TransferFunction>,
    /// A number no other transfer function set in this process had: bumped
    /// whenever `current` changes (what depends on the function keys on it).
    generation: u64,
}

fn entry(binding: u32, ty: wgpu::BindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty,
        count: None,
    }
}

fn buffer(ty: wgpu::BufferBindingType) -> wgpu::BindingType {
    wgpu::BindingType::Buffer {
        ty,
        has_dynamic_offset: false,
        min_binding_size: None,
    }
}

/// Generations of transfer functions, unique in the process: renderers that
/// share a volume plan it with the generation of whichever draws it first.
pub(crate) fn next_generation() -> u64 {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
    NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

/// Group 1's layout: entries (0), prefix sums (1, a table texture), info
/// (2), corrected table (3), its sampler (4, also the other tables'), the
/// pre-integrated table (5) and the spread table (6).
pub(crate) fn layout_entries() -> [wgpu::BindGroupLayoutEntry; 7] {
    let storage = wgpu::BufferBindingType::Storage { read_only: true };
    [
        entry(0, buffer(storage)),
        entry(
            1,
            wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Uint,
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
        ),
        entry(2, buffer(wgpu::BufferBindingType::Uniform)),
        entry(
            3,
            wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: true },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
        ),
        entry(
            4,
            wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
        ),
        entry(
            5,
            wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: true },
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
        ),
        entry(
            6,
            wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: true },
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
        ),
    ]
}

impl TfTables {
    pub(crate) fn new(device: &wgpu::Device) -> Result<TfTables, RenderError> {
        // The corrected, the pre-integrated and the spread table.
        gpu::need(
            "max_sampled_textures_per_shader_stage",
            3,
            device.limits().max_sampled_textures_per_shader_stage as u64,
        )?;
        let layout = gpu::scoped(device, "brickray-render tf layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render transfer function"),
                entries: &layout_entries(),
            })
        })?;
        let sampler = gpu::scoped(device, "brickray-render tf sampler", || {
            device.create_sampler(&wgpu::SamplerDescriptor {
                label: Some("brickray-render tf table"),
                mag_filter: wgpu::FilterMode::Linear,
                min_filter: wgpu::FilterMode::Linear,
                ..Default::default()
            })
        })?;
        Ok(TfTables {
            layout,
            entries: GrowBuffer::new(device, "brickray-render tf", 16)?,
            prefix: TableTexture::new(
                device,
                "brickray-render tf prefix",
                wgpu::TextureFormat::R32Uint,
                TransferFunction::MAX_ENTRIES + 1,
            )?,
            info: Uniform::new(device, "brickray-render tf info")?,
            sampler,
            table: None,
            preint: None,
            spread: None,
            table_key: None,
            preint_key: None,
            spread_key: None,
            bind_group: None,
            current: None,
            generation: 0,
        })
    }

    pub(crate) fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    /// The transfer function set last.
    pub(crate) fn current(&self) -> Option<&TransferFunction> {
        self.current.as_ref()
    }

    /// The generation of the current transfer function (see the field).
    pub(crate) fn generation(&self) -> u64 {
        self.generation
    }

    /// The bind group, once [`Self::prepare`] built the table.
    pub(crate) fn bind_group(&self) -> Option<&wgpu::BindGroup> {
        self.bind_group.as_ref()
    }

    /// Uploads `tf`'s entries and prefix sums (only what changed) and marks the
    /// corrected table stale; returns the bytes written.
    pub(crate) fn set(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        tf: &TransferFunction,
    ) -> Result<u64, RenderError> {
        if self.current.as_ref() == Some(tf) {
            return Ok(0);
        }
        if tf.len() > TransferFunction::MAX_ENTRIES {
            return Err(brickray_core::TfError::TooMany {
                len: tf.len(),
                max: TransferFunction::MAX_ENTRIES,
            }
            .into());
        }
        let (a, grew_a) = self
            .entries
            .write(device, queue, bytemuck::cast_slice(tf.entries()))?;
        let (b, grew_b) = self
            .prefix
            .write(device, queue, bytemuck::cast_slice(tf.prefix()))?;
        if grew_a || grew_b {
            self.bind_group = None;
        }
        self.current = Some(tf.clone());
        self.generation = next_generation();
        self.table_key = None;
        Ok(a + b)
    }

    /// Builds the corrected table of the current TF for `step_factor` and `rows`
    /// step lengths when it is stale (and with `preint` the pre-integrated
    /// table of as many layers, with `spread` the spread table), and the bind
    /// group when a resource changed; returns the bytes written.
    pub(crate) fn prepare(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        step_factor: f32,
        rows: u32,
        preint: bool,
        spread: bool,
    ) -> Result<u64, RenderError> {
        if self.current.is_none() {
            return Ok(0);
        }
        let key = TableKey { step_factor, rows };
        let mut written = 0;
        if self.table_key != Some(key) {
            written += self.write_table(device, queue, key)?;
        }
        written += self.write_preintegrated(device, queue, key, preint)?;
        written += self.write_spread(device, queue, key, spread)?;
        if self.bind_group.is_none() {
            self.bind_group = Some(self.make_bind_group(device)?);
        }
        Ok(written)
    }

    /// The corrected table of the current TF for `key` (recreated when its
    /// size changes) and the TF's uniform.
    fn write_table(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        key: TableKey,
    ) -> Result<u64, RenderError> {
        let Some(tf) = self.current.as_ref() else {
            return Ok(0);
        };
        let max_width = device.limits().max_texture_dimension_2d;
        let t = tf.corrected_table(key.step_factor, key.rows, max_width);
        let count = tf.len();
        let size = wgpu::Extent3d {
            width: t.width,
            height: t.rows,
            depth_or_array_layers: 1,
        };
        if self
            .table
            .as_ref()
            .is_none_or(|(tex, _)| tex.size() != size)
        {
            let tex = table_texture(device, "brickray-render tf table", size)?;
            let view = tex.create_view(&Default::default());
            self.table = Some((tex, view));
            self.bind_group = None;
        }
        let Some((tex, _)) = self.table.as_ref() else {
            return Ok(0);
        };
        let mut written = write_rgba16f(queue, tex, &t.texels, size);
        self.preint_key = None;
        self.spread_key = None;
        written += self.info.write(
            queue,
            TfInfo {
                count: count as f32,
                width: t.width as f32,
                rows: t.rows as f32,
                preint_size: PREINT_SIZE as f32,
            },
        );
        self.table_key = Some(key);
        Ok(written)
    }

    /// The pre-integrated table when asked for and stale; a stand-in until
    /// the first one.
    fn write_preintegrated(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        key: TableKey,
        preint: bool,
    ) -> Result<u64, RenderError> {
        let layers = LayeredTable {
            texture: &mut self.preint,
            built_for: &mut self.preint_key,
            label: "brickray-render tf pre-integrated table",
        };
        let (bytes, recreated) =
            layers.refresh(device, queue, key, preint, self.current.as_ref(), |tf| {
                let t = tf.preintegrated_table(key.step_factor, key.rows.max(1), PREINT_SIZE);
                ArrayTable {
                    width: t.size,
                    height: t.size,
                    layers: t.layers,
                    texels: t.texels,
                }
            })?;
        if recreated {
            self.bind_group = None;
        }
        Ok(bytes)
    }

    /// The spread table when asked for and stale: per step length (layer),
    /// the TF convolved by [`SPREAD_ROWS`] spreads at the corrected table's
    /// width, opacity corrected after the average; a stand-in until the
    /// first one. Its build costs about 0.2 s for a 512-entry TF (one core,
    /// `docs/rendering-model.md`), paid when the TF or the step changes.
    fn write_spread(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        key: TableKey,
        spread: bool,
    ) -> Result<u64, RenderError> {
        let max_width = device.limits().max_texture_dimension_2d;
        let layers = LayeredTable {
            texture: &mut self.spread,
            built_for: &mut self.spread_key,
            label: "brickray-render tf spread table",
        };
        let (bytes, recreated) =
            layers.refresh(device, queue, key, spread, self.current.as_ref(), |tf| {
                let t = tf.spread_table(SPREAD_ROWS, max_width);
                ArrayTable {
                    width: t.width,
                    height: t.rows,
                    layers: key.rows.max(1),
                    texels: t.corrected_layers(key.step_factor, key.rows.max(1)),
                }
            })?;
        if recreated {
            self.bind_group = None;
        }
        Ok(bytes)
    }

    /// Group 1 over the entries, prefix sums, uniform and both tables.
    fn make_bind_group(&self, device: &wgpu::Device) -> Result<wgpu::BindGroup, RenderError> {
        let (Some((_, view)), Some((_, preint_view)), Some((_, spread_view))) = (
            self.table.as_ref(),
            self.preint.as_ref(),
            self.spread.as_ref(),
        ) else {
            return Err(RenderError::NotPrepared);
        };
        gpu::scoped(device, "brickray-render tf bind group", || {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("brickray-render transfer function"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: self.entries.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(&self.prefix.view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: self.info.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: wgpu::BindingResource::TextureView(view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: wgpu::BindingResource::Sampler(&self.sampler),
                    },
                    wgpu::BindGroupEntry {
                        binding: 5,
                        resource: wgpu::BindingResource::TextureView(preint_view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 6,
                        resource: wgpu::BindingResource::TextureView(spread_view),
                    },
                ],
            })
        })
    }
}

/// A sampled 2D (array) texture of `TABLE_FORMAT` texels for a TF table,
/// written by copies.
pub(crate) fn table_texture(
    device: &wgpu::Device,
    label: &'static str,
    size: wgpu::Extent3d,
) -> Result<wgpu::Texture, RenderError> {
    gpu::texture(
        device,
        &wgpu::TextureDescriptor {
            label: Some(label),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: TABLE_FORMAT,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        },
    )
}

/// A table of 2D layers: `layers` of `height` rows of `width` RGBA texels,
/// layer-major, then row, then column.
struct ArrayTable {
    width: u32,
    height: u32,
    layers: u32,
    texels: Vec<[f32; 4]>,
}

/// A table of one layer per step length that is built only while a
/// pipeline needs it (the pre-integrated and the spread table): its texture
/// (a 1x1 stand-in until the first build) and what it was built for.
struct LayeredTable<'a> {
    texture: &'a mut Option<(wgpu::Texture, wgpu::TextureView)>,
    built_for: &'a mut Option<TableKey>,
    label: &'static str,
}

impl LayeredTable<'_> {
    /// Builds the table of `tf` for `key` with `make` when `wanted` and
    /// stale (the layer limit checked before the costly build), or puts the
    /// stand-in in place before the first; returns the bytes written and
    /// whether the texture was recreated (the bind group is then stale).
    fn refresh(
        self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        key: TableKey,
        wanted: bool,
        tf: Option<&TransferFunction>,
        make: impl FnOnce(&TransferFunction) -> ArrayTable,
    ) -> Result<(u64, bool), RenderError> {
        let build = wanted && *self.built_for != Some(key);
        if build {
            gpu::need(
                "max_texture_array_layers",
                key.rows.max(1) as u64,
                device.limits().max_texture_array_layers as u64,
            )?;
        }
        if !build && self.texture.is_some() {
            return Ok((0, false));
        }
        let table = tf.filter(|_| build).map(make);
        let old = self.texture.take();
        let old_size = old.as_ref().map(|(tex, _)| tex.size());
        let (pair, bytes) = upload_array(device, queue, old, table, self.label)?;
        let recreated = old_size != Some(pair.0.size());
        *self.texture = Some(pair);
        *self.built_for = build.then_some(key);
        Ok((bytes, recreated))
    }
}

/// Uploads a table of layers (`None`: a 1x1 transparent stand-in) into
/// `old` when it has the right size, else into a new texture (device limits
/// checked first); returns the texture and view and the bytes written.
fn upload_array(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    old: Option<(wgpu::Texture, wgpu::TextureView)>,
    table: Option<ArrayTable>,
    label: &'static str,
) -> Result<((wgpu::Texture, wgpu::TextureView), u64), RenderError> {
    let (width, height, layers, texels) = match &table {
        Some(t) => (t.width, t.height, t.layers, t.texels.as_slice()),
        None => (1, 1, 1, &[[0.0f32; 4]][..]),
    };
    let size = wgpu::Extent3d {
        width,
        height,
        depth_or_array_layers: layers,
    };
    let pair = match old {
        Some(p) if p.0.size() == size => p,
        _ => {
            let tex = table_texture(device, label, size)?;
            let view = tex.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            });
            (tex, view)
        }
    };
    let bytes = write_rgba16f(queue, &pair.0, texels, size);
    Ok((pair, bytes))
}

/// Writes `texels` (RGBA, converted to half floats) into the whole of
/// `tex`, a `TABLE_FORMAT` texture of `size`; returns the bytes written.
pub(crate) fn write_rgba16f(
    queue: &wgpu::Queue,
    tex: &wgpu::Texture,
    texels: &[[f32; 4]],
    size: wgpu::Extent3d,
) -> u64 {
    let halfs: Vec<u16> = texels
        .iter()
        .flatten()
        .map(|&x| half::f16::from_f32(x).to_bits())
        .collect();
    queue.write_texture(
        tex.as_image_copy(),
        bytemuck::cast_slice(&halfs),
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(size.width * 8),
            rows_per_image: Some(size.height),
        },
        size,
    );
    halfs.len() as u64 * 2
}
