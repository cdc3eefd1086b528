//! A headless host embedding brickray, with no brickray test code: it requests
//! its own adapter, draws an opaque mesh (a floor through the volume), lets
//! brickray `prepare` and `render` into its pass, reads the image back and
//! writes a PNG. The floor hides the volume below it and the volume above the
//! floor is blended over it: depth composites both ways.
//!
//! ```text
//! cargo run -p brickray --example embed_headless -- [out.png]
//! ```

use brickray::{Camera, FrameDesc, TargetDesc, TransferFunction, VolumeFrame, VolumeRenderer};
use wgpu::util::DeviceExt;

const SIZE: (u32, u32) = (256, 192);
const FLOOR: [u8; 3] = [51, 128, 77];
const OUT: &str = "out/embed_headless.png";
const COLOR: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Renders the scene and writes it to `out`; returns the camera used.
fn run(out: &std::path::Path) -> Result<Camera, Box<dyn std::error::Error>> {
    // The host's device, with the limits brickray needs (WebGPU's defaults suffice).
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&Default::default()))?;
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        required_limits: brickray::required_limits().using_resolution(adapter.limits()),
        // Optional: exact 16-bit and float texels where the adapter has them.
        required_features: adapter.features() & brickray::optional_features(),
        ..Default::default()
    }))?;
    // The host's targets: colour (read back), and depth that brickray also samples.
    let (width, height) = SIZE;
    let texture = |format, usage: wgpu::TextureUsages| {
        let t = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("host target"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | usage,
            view_formats: &[],
        });
        (t.create_view(&Default::default()), t)
    };
    let (color_view, color) = texture(COLOR, wgpu::TextureUsages::COPY_SRC);
    let (depth_view, _) = texture(DEPTH, wgpu::TextureUsages::TEXTURE_BINDING);

    // The volume, its placement and the camera (standard depth: cleared to 1).
    let volume = brickray::core::synthetic::sphere(64);
    let frame = VolumeFrame::centered(volume.dims(), [1.0; 3]);
    let camera = Camera::orbit(frame.center(), 2.0, 0.6, 0.3);
    let view_proj = camera.view_proj(width as f32 / height as f32);
    let mut uniform = view_proj.to_cols_array().to_vec();
    uniform.extend(FLOOR.map(|c| c as f32 / 255.0).into_iter().chain([1.0]));

    // The host's own pipeline: an opaque floor, depth-tested and written.
    let module = device.create_shader_module(wgpu::include_wgsl!("floor.wgsl"));
    let floor = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("floor"),
        layout: None,
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: Default::default(),
        depth_stencil: Some(wgpu::DepthStencilState {
            format: DEPTH,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs"),
            compilation_options: Default::default(),
            targets: &[Some(COLOR.into())],
        }),
        multiview_mask: None,
        cache: None,
    });
    let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("floor uniforms"),
        contents: bytemuck::cast_slice(&uniform),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    let floor_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("floor"),
        layout: &floor.get_bind_group_layout(0),
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: uniform.as_entire_binding(),
        }],
    });

    // brickray, for the host's formats.
    let targets = TargetDesc::new(COLOR).with_depth(DEPTH);
    let mut renderer = VolumeRenderer::new(&device, targets)?;
    renderer.set_volume(&device, &queue, &volume)?;
    renderer.set_transfer_function(&device, &queue, &TransferFunction::ramp(0.2, 0.9, 0.4))?;

    // One frame: 1. the host's opaque pass, 2. brickray's compute work (rays
    // stop at the host's depth), 3. a later pass loading colour and depth.
    let mut encoder = device.create_command_encoder(&Default::default());
    let clear = (
        wgpu::LoadOp::Clear(wgpu::Color::BLACK),
        wgpu::LoadOp::Clear(1.0),
    );
    {
        let mut pass = host_pass(&mut encoder, &color_view, &depth_view, clear);
        pass.set_pipeline(&floor);
        pass.set_bind_group(0, &floor_group, &[]);
        pass.draw(0..6, 0..1);
    }
    let desc = FrameDesc {
        host_depth: Some(&depth_view),
        ..FrameDesc::new(camera, frame, width, height)
    };
    renderer.prepare(&device, &queue, &mut encoder, &desc)?;
    {
        let load = (wgpu::LoadOp::Load, wgpu::LoadOp::Load);
        renderer.render(&mut host_pass(&mut encoder, &color_view, &depth_view, load))?;
    }

    // Read back: copy to a buffer with aligned rows, map, wait, write the PNG.
    let row = (4 * width).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("read-back"),
        size: (row * height) as u64,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let layout = wgpu::TexelCopyBufferLayout {
        bytes_per_row: Some(row),
        ..Default::default()
    };
    let dst = wgpu::TexelCopyBufferInfo {
        buffer: &buffer,
        layout,
    };
    encoder.copy_texture_to_buffer(color.as_image_copy(), dst, color.size());
    queue.submit([encoder.finish()]);
    buffer.slice(..).map_async(wgpu::MapMode::Read, |_| {});
    device.poll(wgpu::PollType::wait_indefinitely())?;
    let data = buffer.slice(..).get_mapped_range()?;
    let rows = data.chunks(row as usize);
    let pixels: Vec<u8> = rows
        .flat_map(|r| &r[..4 * width as usize])
        .copied()
        .collect();
    out.parent().map(std::fs::create_dir_all).transpose()?;
    image::save_buffer(out, &pixels, width, height, image::ExtendedColorType::Rgba8)?;
    Ok(camera)
}

/// A render pass over the host's colour and depth with the given load operations.
fn host_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    color: &wgpu::TextureView,
    depth: &wgpu::TextureView,
    (load, depth_load): (wgpu::LoadOp<wgpu::Color>, wgpu::LoadOp<f32>),
) -> wgpu::RenderPass<'e> {
    let store = wgpu::StoreOp::Store;
    encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("host pass"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: color,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations { load, store },
        })],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: depth,
            depth_ops: Some(wgpu::Operations {
                load: depth_load,
                store,
            }),
            stencil_ops: None,
        }),
        ..Default::default()
    })
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args().nth(1).unwrap_or(OUT.into());
    run(out.as_ref()).map(|_| println!("wrote {out}"))
}

#[cfg(test)] // The example's check (run by `cargo test`): it reads the PNG back.
#[path = "checks/embed_headless.rs"]
mod tests;
