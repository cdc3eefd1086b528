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
