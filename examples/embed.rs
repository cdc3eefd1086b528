//! Embedding brickray in a wgpu host, complete: the host owns the device, its
//! colour and depth targets and its opaque geometry; brickray records its work
//! into the host's encoder and draws into the host's pass.
//!
//! ```text
//! cargo run -p brickray --example embed -- [out.png]
//! ```
//! Renders a procedural sphere over a host-cleared target with a reversed-Z
//! infinite projection (as Bevy uses) and writes `out/embed.png`.

use brickray::{
    Camera, DepthConvention, FrameDesc, TargetDesc, TransferFunction, VolumeFrame, VolumeRenderer,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "out/embed.png".into());
    // The host's device: brickray never creates one. It needs at most
    // `brickray::required_limits()` (within WebGPU's defaults).
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&Default::default()))?;
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        required_limits: brickray::required_limits().using_resolution(adapter.limits()),
        ..Default::default()
    }))?;

    // The host's targets: colour, and a depth buffer it can also sample.
    let (width, height) = (256, 192);
    let color_format = wgpu::TextureFormat::Rgba8Unorm;
    let depth_format = wgpu::TextureFormat::Depth32Float;
    let target = |format, usage| {
        device.create_texture(&wgpu::TextureDescriptor {
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
        })
    };
    let color = target(color_format, wgpu::TextureUsages::COPY_SRC);
    let depth = target(depth_format, wgpu::TextureUsages::TEXTURE_BINDING);
    let color_view = color.create_view(&Default::default());
    let depth_view = depth.create_view(&Default::default());

    // Set-up: the renderer for the host's formats, a volume, a transfer function.
    let targets = TargetDesc::new(color_format).with_depth(depth_format);
    let mut renderer = VolumeRenderer::new(&device, targets)?;
    let volume = brickray::core::synthetic::sphere(64);
    renderer.set_volume(&device, &queue, &volume)?;
    renderer.set_transfer_function(&device, &queue, &TransferFunction::ramp(0.2, 0.9, 0.4))?;

    // One frame. The camera's depth convention is the host's: reversed-Z with an
    // infinite far plane here, so the host clears depth to 0.
    let frame = VolumeFrame::centered(volume.dims(), [1.0; 3]);
    let camera = Camera {
        far: f32::INFINITY,
        depth: DepthConvention::ReversedZ,
        ..Camera::orbit(frame.center(), 2.0, 0.6, 0.3)
    };
    let mut encoder = device.create_command_encoder(&Default::default());
    // 1. The host's opaque pass (here it only clears; geometry would go here).
    let clear = wgpu::Color {
        r: 0.1,
        g: 0.1,
        b: 0.15,
        a: 1.0,
    };
    drop(host_pass(
        &mut encoder,
        &color_view,
        &depth_view,
        wgpu::LoadOp::Clear(clear),
        wgpu::LoadOp::Clear(camera.depth.far_value()),
    ));
    // 2. brickray's compute work, recorded after the opaque pass: rays stop at
    //    the host's depth.
    let desc = FrameDesc {
        host_depth: Some(&depth_view),
        ..FrameDesc::new(camera, frame, width, height)
    };
    renderer.prepare(&device, &queue, &mut encoder, &desc)?;
    // 3. A later pass that loads colour and depth; brickray draws into it, and
    //    geometry drawn after it is depth-tested against the volume.
    {
        let (load_color, load_depth) = (wgpu::LoadOp::Load, wgpu::LoadOp::Load);
        let mut pass = host_pass(
            &mut encoder,
            &color_view,
            &depth_view,
            load_color,
            load_depth,
        );
        renderer.render(&mut pass)?;
    }
    queue.submit([encoder.finish()]);

    // Read the image back (a host would present it instead).
    save_png(&device, &queue, &color, &out)?;
    println!("wrote {out}");
    Ok(())
}

/// A render pass over the host's colour and depth.
fn host_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    color: &wgpu::TextureView,
    depth: &wgpu::TextureView,
    load_color: wgpu::LoadOp<wgpu::Color>,
    load_depth: wgpu::LoadOp<f32>,
) -> wgpu::RenderPass<'e> {
    encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("host pass"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: color,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: load_color,
                store: wgpu::StoreOp::Store,
            },
        })],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: depth,
            depth_ops: Some(wgpu::Operations {
                load: load_depth,
                store: wgpu::StoreOp::Store,
            }),
            stencil_ops: None,
        }),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    })
}

/// Copies an RGBA8 texture to a buffer, waits for it and writes a PNG.
fn save_png(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    path: &str,
) -> Result<(), Box<dyn std::error::Error>> {
    let (w, h) = (texture.width(), texture.height());
    let row = (4 * w).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: row as u64 * h as u64,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row),
                rows_per_image: Some(h),
            },
        },
        texture.size(),
    );
    queue.submit([encoder.finish()]);
    buffer.slice(..).map_async(wgpu::MapMode::Read, |_| {});
    device.poll(wgpu::PollType::wait_indefinitely())?;
    let data = buffer.slice(..).get_mapped_range()?;
    let pixels: Vec<u8> = data
        .chunks(row as usize)
        .flat_map(|r| &r[..4 * w as usize])
        .copied()
        .collect();
    if let Some(dir) = std::path::Path::new(path).parent() {
        std::fs::create_dir_all(dir)?;
    }
    image::save_buffer(path, &pixels, w, h, image::ExtendedColorType::Rgba8)?;
    Ok(())
}
