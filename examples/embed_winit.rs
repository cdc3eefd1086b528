//! brickray in a plain winit window: the host owns the window, the surface, the
//! device and a depth buffer; brickray records its work into the host's encoder
//! and draws into the host's pass. Drag with the left mouse button to orbit,
//! scroll to zoom. No GUI toolkit, no brickray test code.
//!
//! ```text
//! cargo run -p brickray --example embed_winit -- [--frames N]
//! ```
//! With `--frames N` it closes itself after drawing N frames.

use brickray::{Camera, FrameDesc, TargetDesc, TransferFunction, VolumeFrame, VolumeRenderer};
use std::sync::Arc;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::window::{Window, WindowId};

/// What the host holds once its window exists.
struct Gpu {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    depth: wgpu::TextureView,
    renderer: VolumeRenderer,
    frame: VolumeFrame,
}

/// The application: the orbit (yaw, pitch, distance), the mouse, the frame count.
#[derive(Default)]
struct App {
    gpu: Option<Gpu>,
    orbit: (f32, f32, f32),
    drag: Option<(f64, f64)>,
    cursor: (f64, f64),
    frames_left: Option<u32>,
    drawn: u32,
    error: Option<Box<dyn std::error::Error>>,
}

const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

fn depth_view(device: &wgpu::Device, config: &wgpu::SurfaceConfiguration) -> wgpu::TextureView {
    let size = wgpu::Extent3d {
        width: config.width,
        height: config.height,
        depth_or_array_layers: 1,
    };
    let usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
    device
        .create_texture(&wgpu::TextureDescriptor {
            label: Some("host depth"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage,
            view_formats: &[],
        })
        .create_view(&Default::default())
}

impl Gpu {
    fn new(event_loop: &ActiveEventLoop) -> Result<Gpu, Box<dyn std::error::Error>> {
        let attrs = Window::default_attributes()
            .with_title("brickray embed_winit")
            .with_inner_size(winit::dpi::PhysicalSize::new(256, 256));
        let window = Arc::new(event_loop.create_window(attrs)?);
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let surface = instance.create_surface(window.clone())?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            compatible_surface: Some(&surface),
            ..Default::default()
        }))?;
        let (device, queue) =
            pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
                required_limits: brickray::required_limits().using_resolution(adapter.limits()),
                required_features: adapter.features() & brickray::optional_features(),
                ..Default::default()
            }))?;
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .ok_or("the surface does not work with this adapter")?;
        // A non-sRGB format when there is one: the same colours as the
        // headless example and egui (brickray writes its colours as they are).
        let formats = surface.get_capabilities(&adapter).formats;
        if let Some(&f) = formats.iter().find(|f| !f.is_srgb()) {
            config.format = f;
        }
        surface.configure(&device, &config);
        let depth = depth_view(&device, &config);
        let targets = TargetDesc::new(config.format).with_depth(DEPTH_FORMAT);
        let mut renderer = VolumeRenderer::new(&device, targets)?;
        let volume = brickray::core::synthetic::sphere(64);
        renderer.set_volume(&device, &queue, &volume)?;
        renderer.set_transfer_function(&device, &queue, &TransferFunction::ramp(0.2, 0.9, 0.4))?;
        let frame = VolumeFrame::centered(volume.dims(), [1.0; 3]);
        Ok(Gpu {
            window,
            surface,
            device,
            queue,
            config,
            depth,
            renderer,
            frame,
        })
    }

    fn resize(&mut self, width: u32, height: u32) {
        self.config.width = width.max(1);
        self.config.height = height.max(1);
        self.surface.configure(&self.device, &self.config);
        self.depth = depth_view(&self.device, &self.config);
    }

    /// One frame: the host's (here empty) opaque pass, brickray's compute work,
    /// then brickray's draw in a pass loading colour and depth; present.
    /// Returns false when the surface had no texture to draw into this time.
    fn draw(&mut self, camera: Camera) -> Result<bool, Box<dyn std::error::Error>> {
        use wgpu::CurrentSurfaceTexture as Current;
        let texture = match self.surface.get_current_texture() {
            Current::Success(t) | Current::Suboptimal(t) => t,
            Current::Timeout | Current::Occluded => return Ok(false),
            Current::Outdated => {
                self.surface.configure(&self.device, &self.config);
                return Ok(false);
            }
            other => return Err(format!("no surface texture: {other:?}").into()),
        };
        let view = texture.texture.create_view(&Default::default());
        let mut encoder = self.device.create_command_encoder(&Default::default());
        let clear = wgpu::Color {
            r: 0.1,
            g: 0.1,
            b: 0.15,
            a: 1.0,
        };
        drop(pass(
            &mut encoder,
            &view,
            &self.depth,
            wgpu::LoadOp::Clear(clear),
            wgpu::LoadOp::Clear(1.0),
        ));
        let (w, h) = (self.config.width, self.config.height);
        let desc = FrameDesc {
            host_depth: Some(&self.depth),
            ..FrameDesc::new(camera, self.frame, w, h)
        };
        self.renderer
            .prepare(&self.device, &self.queue, &mut encoder, &desc)?;
        let mut p = pass(
            &mut encoder,
            &view,
            &self.depth,
            wgpu::LoadOp::Load,
            wgpu::LoadOp::Load,
        );
        self.renderer.render(&mut p)?;
        drop(p);
        self.queue.submit([encoder.finish()]);
        self.window.pre_present_notify();
        self.queue.present(texture);
        Ok(true)
    }
}

fn pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    color: &wgpu::TextureView,
    depth: &wgpu::TextureView,
    load: wgpu::LoadOp<wgpu::Color>,
    load_depth: wgpu::LoadOp<f32>,
) -> wgpu::RenderPass<'e> {
    encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("host pass"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: color,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load,
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
        ..Default::default()
    })
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: Box<dyn std::error::Error>) {
        self.error = Some(e);
        event_loop.exit();
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.gpu.is_none() {
            match Gpu::new(event_loop) {
                Ok(gpu) => self.gpu = Some(gpu),
                Err(e) => self.fail(event_loop, e),
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        let Some(gpu) = self.gpu.as_mut() else { return };
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => gpu.resize(size.width, size.height),
            WindowEvent::MouseInput {
                state,
                button: MouseButton::Left,
                ..
            } => {
                self.drag = (state == ElementState::Pressed).then_some(self.cursor);
            }
            WindowEvent::CursorMoved { position, .. } => {
                self.cursor = (position.x, position.y);
                if let Some((x, y)) = self.drag.replace(self.cursor) {
                    self.orbit.0 -= (position.x - x) as f32 * 0.01;
                    self.orbit.1 = (self.orbit.1 + (position.y - y) as f32 * 0.01).clamp(-1.5, 1.5);
                    gpu.window.request_redraw();
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
                self.orbit.2 = (self.orbit.2 * 0.9f32.powf(lines)).clamp(0.2, 20.0);
                gpu.window.request_redraw();
            }
            WindowEvent::RedrawRequested => {
                let (yaw, pitch, distance) = self.orbit;
                let camera = Camera::orbit(gpu.frame.center(), distance, yaw, pitch);
                match gpu.draw(camera) {
                    Ok(true) => self.drawn += 1,
                    Ok(false) => return gpu.window.request_redraw(),
                    Err(e) => return self.fail(event_loop, e),
                }
                // Out of core, bricks may still be arriving: draw again soon.
                if gpu.renderer.wants_redraw() {
                    gpu.window.request_redraw();
                }
                if let Some(n) = self.frames_left.as_mut() {
                    *n = n.saturating_sub(1);
                    if *n == 0 {
                        event_loop.exit();
                    } else {
                        gpu.window.request_redraw();
                    }
                }
            }
            _ => {}
        }
    }
}

/// Runs the window until it is closed (or `frames` frames were drawn); returns
/// the frames drawn.
fn run(event_loop: EventLoop<()>, frames: Option<u32>) -> Result<u32, Box<dyn std::error::Error>> {
    let mut app = App {
        orbit: (0.6, 0.3, 2.0),
        frames_left: frames,
        ..Default::default()
    };
    event_loop.run_app(&mut app)?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(app.drawn),
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let frames = match args.as_slice() {
        [] => None,
        [flag, n] if flag == "--frames" => Some(n.parse()?),
        _ => return Err("usage: embed_winit [--frames N]".into()),
    };
    let drawn = run(EventLoop::new()?, frames)?;
    println!("drew {drawn} frames");
    Ok(())
}

#[cfg(test)] // The example's check (run by `cargo test`, under Xvfb in CI).
#[path = "checks/embed_winit.rs"]
mod tests;
