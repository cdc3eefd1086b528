//! Small GPU helpers shared by the owners: limit-checked buffer creation, a
//! grow-only buffer, and error scopes that turn a wgpu error into a typed one.

use crate::error::{GpuErrorKind, RenderError};
use std::future::Future;
use std::pin::pin;
use std::task::{Context, Poll, Waker};

/// Runs `create` inside validation, out-of-memory and internal error scopes and
/// returns its value, or the first error wgpu reported as a typed
/// [`RenderError::Gpu`] naming `what`. The library checks every limit it knows
/// before creating an object, so this only catches what those checks miss; an
/// error here is a bug to report.
///
/// On native backends the scopes resolve at once. Where they would resolve later
/// (WebGPU), the error is left to the device's uncaptured-error handler.
pub(crate) fn scoped<T>(
    device: &wgpu::Device,
    what: &'static str,
    create: impl FnOnce() -> T,
) -> Result<T, RenderError> {
    let internal = device.push_error_scope(wgpu::ErrorFilter::Internal);
    let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let out = create();
    // Scopes pop in the reverse order of their pushes.
    let errors = [
        ready(validation.pop()),
        ready(oom.pop()),
        ready(internal.pop()),
    ];
    match errors.into_iter().flatten().next() {
        None => Ok(out),
        Some(e) => Err(gpu_error(what, e)),
    }
}

fn gpu_error(what: &'static str, e: wgpu::Error) -> RenderError {
    let kind = match &e {
        wgpu::Error::OutOfMemory { .. } => GpuErrorKind::OutOfMemory,
        wgpu::Error::Validation { .. } => GpuErrorKind::Validation,
        _ => GpuErrorKind::Internal,
    };
    RenderError::Gpu {
        what,
        kind,
        message: e.to_string(),
    }
}

/// The value of a future that is already complete, `None` if it is not.
fn ready<T>(f: impl Future<Output = Option<T>>) -> Option<T> {
    let mut f = pin!(f);
    match f.as_mut().poll(&mut Context::from_waker(Waker::noop())) {
        Poll::Ready(v) => v,
        Poll::Pending => None,
    }
}

/// The workgroup of both ray casters and the reprojection pass: 8 x 8
/// invocations, one per pixel.
pub(crate) const WORKGROUP: [u32; 2] = [8, 8];

/// Fails with [`RenderError::LowDeviceLimit`] when `required > available`.
pub(crate) fn need(limit: &'static str, required: u64, available: u64) -> Result<(), RenderError> {
    if required > available {
        Err(RenderError::LowDeviceLimit {
            limit,
            required,
            available,
        })
    } else {
        Ok(())
    }
}

/// A `STORAGE | COPY_DST` buffer of `size` bytes, checked against the device's
/// storage-binding and buffer-size limits first. `what` labels it.
pub(crate) fn storage_buffer(
    device: &wgpu::Device,
    what: &'static str,
    size: u64,
) -> Result<wgpu::Buffer, RenderError> {
    let limits = device.limits();
    let size = size.max(16).next_multiple_of(4);
    need(
        "max_storage_buffer_binding_size",
        size,
        limits.max_storage_buffer_binding_size,
    )?;
    need("max_buffer_size", size, limits.max_buffer_size)?;
    scoped(device, what, || {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(what),
            size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    })
}

/// A buffer of `size` bytes with `usage`, checked against the device's
/// buffer-size limit (and the storage-binding limit when it is `STORAGE`).
pub(crate) fn buffer(
    device: &wgpu::Device,
    what: &'static str,
    size: u64,
    usage: wgpu::BufferUsages,
) -> Result<wgpu::Buffer, RenderError> {
    let limits = device.limits();
    let size = size.max(16).next_multiple_of(4);
    if usage.contains(wgpu::BufferUsages::STORAGE) {
        need(
            "max_storage_buffer_binding_size",
            size,
            limits.max_storage_buffer_binding_size,
        )?;
    }
    need("max_buffer_size", size, limits.max_buffer_size)?;
    scoped(device, what, || {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(what),
            size,
            usage,
            mapped_at_creation: false,
        })
    })
}

/// A `UNIFORM | COPY_DST` buffer for one `T`, checked against the uniform-binding
/// limit first.
pub(crate) fn uniform_buffer<T>(
    device: &wgpu::Device,
    what: &'static str,
) -> Result<wgpu::Buffer, RenderError> {
    let size = std::mem::size_of::<T>() as u64;
    need(
        "max_uniform_buffer_binding_size",
        size,
        device.limits().max_uniform_buffer_binding_size,
    )?;
    scoped(device, what, || {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(what),
            size,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    })
}

/// A uniform buffer and the last value written to it: written only on change.
#[derive(Debug)]
pub(crate) struct Uniform<T> {
    pub(crate) buffer: wgpu::Buffer,
    last: Option<T>,
}

impl<T: bytemuck::Pod + PartialEq> Uniform<T> {
    pub(crate) fn new(device: &wgpu::Device, what: &'static str) -> Result<Self, RenderError> {
        Ok(Uniform {
            buffer: uniform_buffer::<T>(device, what)?,
            last: None,
        })
    }

    /// Writes `value` if it differs from the last one; returns the bytes written.
    pub(crate) fn write(&mut self, queue: &wgpu::Queue, value: T) -> u64 {
        if self.last == Some(value) {
            return 0;
        }
        queue.write_buffer(&self.buffer, 0, bytemuck::bytes_of(&value));
        self.last = Some(value);
        std::mem::size_of::<T>() as u64
    }

    /// The last value written.
    pub(crate) fn last(&self) -> Option<T> {
        self.last
    }
}

/// A storage buffer that grows geometrically and is rewritten only on change.
#[derive(Debug)]
pub(crate) struct GrowBuffer {
    label: &'static str,
    pub(crate) buffer: wgpu::Buffer,
    contents: Vec<u8>,
}

impl GrowBuffer {
    pub(crate) fn new(
        device: &wgpu::Device,
        label: &'static str,
        size: u64,
    ) -> Result<GrowBuffer, RenderError> {
        Ok(GrowBuffer {
            label,
            buffer: storage_buffer(device, label, size)?,
            contents: Vec::new(),
        })
    }

    /// Writes `data`; returns (bytes written, whether the buffer was reallocated,
    /// so bind groups holding it must be rebuilt).
    pub(crate) fn write(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        data: &[u8],
    ) -> Result<(u64, bool), RenderError> {
        if data == self.contents.as_slice() {
            return Ok((0, false));
        }
        let mut grown = false;
        if data.len() as u64 > self.buffer.size() {
            let size = (data.len() as u64).next_power_of_two();
            let limit = device.limits().max_storage_buffer_binding_size;
            // Grow geometrically, but never past the binding limit.
            let size = if size > limit {
                data.len() as u64
            } else {
                size
            };
            self.buffer = storage_buffer(device, self.label, size)?;
            grown = true;
        }
        queue.write_buffer(&self.buffer, 0, data);
        self.contents.clear();
        self.contents.extend_from_slice(data);
        Ok((data.len() as u64, grown))
    }
}

/// Texels per row of a [`TableTexture`] (WebGPU's default
/// `max_texture_dimension_2d` is 8192; 2048 is what downlevel devices give).
pub(crate) const TABLE_ROW: u32 = 2048;

/// A read-only table the kernels read with `textureLoad`, entry `i` at
/// texel `(i % TABLE_ROW, i / TABLE_ROW)`, rather than from a storage
/// buffer: on lavapipe a storage-buffer load whose address differs between
/// lanes runs as a loop over the lanes with a branch per lane and
/// component, a texel fetch as one gather (docs/rendering-model.md,
/// "Tables in textures").
#[derive(Debug)]
pub(crate) struct TableTexture {
    label: &'static str,
    format: wgpu::TextureFormat,
    texel_bytes: usize,
    texture: wgpu::Texture,
    pub(crate) view: wgpu::TextureView,
    /// What [`write`](Self::write) wrote last (empty after a `write_at`).
    contents: Vec<u8>,
}

impl TableTexture {
    /// A table of `format`'s texels (an uncompressed colour format) with
    /// room for at least `texels` entries.
    pub(crate) fn new(
        device: &wgpu::Device,
        label: &'static str,
        format: wgpu::TextureFormat,
        texels: usize,
    ) -> Result<TableTexture, RenderError> {
        let rows = texels.div_ceil(TABLE_ROW as usize).max(1) as u32;
        let (texture, view) = Self::create(device, label, format, rows)?;
        Ok(TableTexture {
            label,
            format,
            texel_bytes: format.block_copy_size(None).unwrap_or(4) as usize,
            texture,
            view,
            contents: Vec::new(),
        })
    }

    fn create(
        device: &wgpu::Device,
        label: &'static str,
        format: wgpu::TextureFormat,
        rows: u32,
    ) -> Result<(wgpu::Texture, wgpu::TextureView), RenderError> {
        let texture = texture(
            device,
            &wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width: TABLE_ROW,
                    height: rows,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            },
        )?;
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok((texture, view))
    }

    /// Entries the table has room for.
    pub(crate) fn capacity(&self) -> usize {
        TABLE_ROW as usize * self.texture.height() as usize
    }

    /// Writes the whole table, `data` (whole texels) from entry 0, growing
    /// its rows geometrically where it needs more; unchanged data is not
    /// written again. Returns (bytes written, whether the texture was
    /// recreated, so bind groups holding it must be rebuilt).
    pub(crate) fn write(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        data: &[u8],
    ) -> Result<(u64, bool), RenderError> {
        if data == self.contents.as_slice() {
            return Ok((0, false));
        }
        let rows = (data.len() / self.texel_bytes).div_ceil(TABLE_ROW as usize) as u32;
        let mut grown = false;
        if rows > self.texture.height() {
            let max = device.limits().max_texture_dimension_2d;
            let alloc = rows.next_power_of_two().min(max).max(rows);
            (self.texture, self.view) = Self::create(device, self.label, self.format, alloc)?;
            grown = true;
        }
        self.write_at(queue, 0, data);
        self.contents.clear();
        self.contents.extend_from_slice(data);
        Ok((data.len() as u64, grown))
    }

    /// Writes `data` (whole texels) from entry `first`, within the table's
    /// room (what lies past it is not written: the caller sized the table).
    pub(crate) fn write_at(&mut self, queue: &wgpu::Queue, first: usize, data: &[u8]) {
        self.contents.clear();
        let texels = (data.len() / self.texel_bytes).min(self.capacity().saturating_sub(first));
        for p in table_pieces(first, texels) {
            let bytes =
                &data[p.from * self.texel_bytes..(p.from + p.width * p.height) * self.texel_bytes];
            let (x, y, width, height) = (p.x, p.y, p.width, p.height);
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &self.texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x: x as u32,
                        y: y as u32,
                        z: 0,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                bytes,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some((width * self.texel_bytes) as u32),
                    rows_per_image: None,
                },
                wgpu::Extent3d {
                    width: width as u32,
                    height: height as u32,
                    depth_or_array_layers: 1,
                },
            );
        }
    }
}

/// One rectangle of a table write: `width` x `height` texels at (`x`,
/// `y`), from entry `from` of the data written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct TablePiece {
    pub(crate) x: usize,
    pub(crate) y: usize,
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) from: usize,
}

/// The rectangles that write `texels` entries from entry `first` of a
/// table: a partial first row, the whole rows, a partial last row (each
/// where there is one).
pub(crate) fn table_pieces(first: usize, texels: usize) -> Vec<TablePiece> {
    let row = TABLE_ROW as usize;
    let mut out = Vec::new();
    let mut done = 0;
    while done < texels {
        let at = first + done;
        let (x, y) = (at % row, at / row);
        let (width, height) = if x > 0 || texels - done < row {
            ((row - x).min(texels - done), 1)
        } else {
            (row, (texels - done) / row)
        };
        out.push(TablePiece {
            x,
            y,
            width,
            height,
            from: done,
        });
        done += width * height;
    }
    out
}

/// A limit-checked texture: its size against the dimension limit of its kind.
pub(crate) fn texture(
    device: &wgpu::Device,
    desc: &wgpu::TextureDescriptor<'static>,
) -> Result<wgpu::Texture, RenderError> {
    let limits = device.limits();
    let s = desc.size;
    match desc.dimension {
        wgpu::TextureDimension::D3 => {
            let m = s.width.max(s.height).max(s.depth_or_array_layers) as u64;
            need(
                "max_texture_dimension_3d",
                m,
                limits.max_texture_dimension_3d as u64,
            )?;
        }
        _ => {
            let m = s.width.max(s.height) as u64;
            need(
                "max_texture_dimension_2d",
                m,
                limits.max_texture_dimension_2d as u64,
            )?;
            need(
                "max_texture_array_layers",
                s.depth_or_array_layers as u64,
                limits.max_texture_array_layers as u64,
            )?;
        }
    }
    scoped(
        device,
        desc.label.unwrap_or("brickray-render texture"),
        || device.create_texture(desc),
    )
}

/// A volume in one limit-checked 3D texture of `enc`'s format, uploaded in
/// slabs of at most 64 MiB so staging memory stays bounded (each slab is
/// converted on its own: no full-volume copy in the texel format). Returns
/// the texture and its bytes.
pub(crate) fn volume_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    vol: &brickray_core::Volume,
    enc: &brickray_core::SampleEncoding,
    label: &'static str,
) -> Result<(wgpu::Texture, u64), RenderError> {
    let dims = vol.dims();
    let src = vol.data().as_bytes();
    let src_slice = dims[0] as usize * dims[1] as usize * vol.desc().dtype.size();
    slab_texture(
        device,
        queue,
        dims,
        crate::encoding::wgpu_format(enc.format),
        enc.texel_bytes(),
        label,
        |z0, z1| enc.encode(&src[z0 * src_slice..z1 * src_slice]),
    )
}

/// A compute pass's uniform of type `T` at `binding`.
pub(crate) fn uniform_entry<T>(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<T>() as u64),
        },
        count: None,
    }
}

/// The layout of one bind group of `entries` and a compute pipeline over it
/// running `wgsl`'s `main` (a pass of its own: the gradients, the
/// prediction's reprojection), each made inside a validation scope.
pub(crate) fn single_group_pipeline(
    device: &wgpu::Device,
    label: &'static str,
    entries: &[wgpu::BindGroupLayoutEntry],
    wgsl: &str,
) -> Result<(wgpu::BindGroupLayout, wgpu::ComputePipeline), RenderError> {
    scoped(device, label, || {
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(wgsl.into()),
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: Some(&pl),
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        (layout, pipeline)
    })
}

/// A compute-stage storage buffer of group layout entry `binding`, any size.
pub(crate) fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
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

/// A limit-checked, sampled 3D texture of `dims` texels of `format`,
/// written by copies.
pub(crate) fn sampled_3d(
    device: &wgpu::Device,
    dims: [u32; 3],
    format: wgpu::TextureFormat,
    label: &'static str,
) -> Result<wgpu::Texture, RenderError> {
    texture_3d(
        device,
        dims,
        format,
        wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        label,
    )
}

/// A limit-checked 3D texture of `dims` texels of `format` with `usage`.
pub(crate) fn texture_3d(
    device: &wgpu::Device,
    dims: [u32; 3],
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
    label: &'static str,
) -> Result<wgpu::Texture, RenderError> {
    texture(
        device,
        &wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width: dims[0],
                height: dims[1],
                depth_or_array_layers: dims[2],
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format,
            usage,
            view_formats: &[],
        },
    )
}

/// A limit-checked 3D texture of `dims` texels of `format` (`texel_bytes`
/// each), written in slabs of at most 64 MiB whose texels `slab(z0, z1)`
/// makes (slices `z0..z1`, x fastest). Returns the texture and its bytes.
pub(crate) fn slab_texture<'a>(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    dims: [u32; 3],
    format: wgpu::TextureFormat,
    texel_bytes: u32,
    label: &'static str,
    slab: impl Fn(usize, usize) -> std::borrow::Cow<'a, [u8]>,
) -> Result<(wgpu::Texture, u64), RenderError> {
    let row = dims[0] * texel_bytes;
    let slice = row as usize * dims[1] as usize;
    let bytes = slice as u64 * dims[2] as u64;
    let texture = sampled_3d(device, dims, format, label)?;
    let per = ((64usize << 20) / slice.max(1)).clamp(1, dims[2] as usize) as u32;
    let mut z = 0;
    while z < dims[2] {
        let z1 = (z + per).min(dims[2]);
        let texels = slab(z as usize, z1 as usize);
        scoped(device, label, || {
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: 0, z },
                    aspect: wgpu::TextureAspect::All,
                },
                &texels,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: Some(dims[1]),
                },
                wgpu::Extent3d {
                    width: dims[0],
                    height: dims[1],
                    depth_or_array_layers: z1 - z,
                },
            )
        })?;
        z = z1;
    }
    Ok((texture, bytes))
}

#[cfg(test)]
mod tests {
    use super::{TABLE_ROW, table_pieces};

    /// Every entry of a write lands once, at (i % TABLE_ROW, i / TABLE_ROW),
    /// in rectangles within the rows, read from its place in the data.
    #[test]
    fn table_pieces_cover_each_entry_once_at_its_texel() {
        let row = TABLE_ROW as usize;
        for first in [0, 1, 5, row - 1, row, row + 7, 3 * row] {
            for texels in [
                0,
                1,
                2,
                row - 1,
                row,
                row + 1,
                2 * row,
                3 * row + 5,
                5 * row - first % row,
            ] {
                let pieces = table_pieces(first, texels);
                let mut seen = vec![0u8; texels];
                for p in &pieces {
                    assert!(p.width > 0 && p.height > 0 && p.x + p.width <= row, "{p:?}");
                    assert!(p.height == 1 || (p.x == 0 && p.width == row), "{p:?}");
                    for dy in 0..p.height {
                        for dx in 0..p.width {
                            let k = p.from + dy * p.width + dx;
                            let at = first + k;
                            assert_eq!((at % row, at / row), (p.x + dx, p.y + dy));
                            seen[k] += 1;
                        }
                    }
                }
                assert!(
                    seen.iter().all(|&c| c == 1),
                    "first {first}, texels {texels}"
                );
                assert!(pieces.len() <= 3, "{pieces:?}");
            }
        }
    }
}
