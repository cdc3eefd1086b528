//! The volume view: brickray drawn into egui's frame through egui-wgpu's paint
//! callback, the way any host embeds it. egui's render pass is the host's
//! pass (its colour target and a `Depth32Float` depth buffer), the callback's
//! rectangle is the viewport, and the viewer's own geometry (the bounding box
//! and axes) composites with the volume by depth in both directions:
//!
//! 1. `prepare` (egui's encoder): a depth-only pass draws the lines into the
//!    viewer's host-depth texture, then `VolumeRenderer::prepare` records the
//!    ray cast, whose rays stop at that depth;
//! 2. `paint` (egui's pass): the lines are drawn with colour and depth, then
//!    `VolumeRenderer::render` blends the volume over them and writes depth.

use brickray::{
    Camera, FrameDesc, RenderSettings, SliceView, TargetDesc, Viewport, VolumeFrame, VolumeRenderer,
};
use eframe::{egui, egui_wgpu};
use glam::{Mat4, Vec3};
use std::sync::Mutex;

/// The depth format of egui's pass (`NativeOptions::depth_buffer = 32`) and of
/// the host-depth texture.
pub(crate) const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// A line vertex: position (w unused) and colour.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct LineVertex {
    position: [f32; 4],
    color: [f32; 4],
}

/// The bounding box's 12 edges and three axes from the volume's origin
/// corner (x red, y green, z blue), in world space.
fn overlay_lines(frame: &VolumeFrame) -> Vec<LineVertex> {
    let corner = |i: u32| {
        let p = Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, (i >> 2) as f32);
        frame.model.transform_point3(p)
    };
    let grey = [0.55, 0.55, 0.6, 1.0];
    let mut v = Vec::with_capacity(30);
    let mut line = |a: Vec3, b: Vec3, color: [f32; 4]| {
        v.push(LineVertex {
            position: a.extend(1.0).to_array(),
            color,
        });
        v.push(LineVertex {
            position: b.extend(1.0).to_array(),
            color,
        });
    };
    for i in 0..8u32 {
        for bit in [1u32, 2, 4] {
            if i & bit == 0 {
                line(corner(i), corner(i | bit), grey);
            }
        }
    }
    let o = corner(0);
    let axes = [
        (Vec3::X, [0.9, 0.2, 0.2, 1.0]),
        (Vec3::Y, [0.2, 0.85, 0.2, 1.0]),
        (Vec3::Z, [0.25, 0.4, 1.0, 1.0]),
    ];
    for (axis, color) in axes {
        let end = frame.model.transform_point3(axis * 1.25);
        line(o, end, color);
    }
    v
}

/// The GPU side of the overlay lines.
#[derive(Debug)]
struct Overlay {
    depth_only: wgpu::RenderPipeline,
    colored: wgpu::RenderPipeline,
    uniforms: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    vertices: Option<(wgpu::Buffer, u32, VolumeFrame)>,
    view_proj: Option<Mat4>,
}

impl Overlay {
    fn new(device: &wgpu::Device, color_format: wgpu::TextureFormat) -> Overlay {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("brickray-viewer overlay.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../shaders/overlay.wgsl").into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("brickray-viewer overlay"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: wgpu::BufferSize::new(64),
                },
                count: None,
            }],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("brickray-viewer overlay"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let attributes = wgpu::vertex_attr_array![0 => Float32x4, 1 => Float32x4];
        let buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<LineVertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &attributes,
        })];
        let pipeline = |color: bool| {
            let targets = [Some(wgpu::ColorTargetState {
                format: color_format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })];
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(if color {
                    "brickray-viewer overlay"
                } else {
                    "brickray-viewer overlay depth"
                }),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &buffers,
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::LineList,
                    ..Default::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Less),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: color.then(|| wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs_main"),
                    compilation_options: Default::default(),
                    targets: &targets,
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("brickray-viewer overlay uniforms"),
            size: 64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("brickray-viewer overlay"),
            layout: &layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: uniforms.as_entire_binding(),
            }],
        });
        Overlay {
            depth_only: pipeline(false),
            colored: pipeline(true),
            uniforms,
            bind_group,
            vertices: None,
            view_proj: None,
        }
    }

    /// Writes the view-projection and (when the volume moved) the lines.
    fn update(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        frame: &VolumeFrame,
        view_proj: Mat4,
    ) {
        // Uniforms are written only when they change.
        if self.view_proj != Some(view_proj) {
            self.view_proj = Some(view_proj);
            queue.write_buffer(
                &self.uniforms,
                0,
                bytemuck::cast_slice(&view_proj.to_cols_array()),
            );
        }
        if self.vertices.as_ref().is_some_and(|v| v.2 == *frame) {
            return;
        }
        let lines = overlay_lines(frame);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("brickray-viewer overlay lines"),
            size: std::mem::size_of_val(lines.as_slice()) as u64,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        queue.write_buffer(&buffer, 0, bytemuck::cast_slice(&lines));
        self.vertices = Some((buffer, lines.len() as u32, *frame));
    }

    fn draw(&self, pass: &mut wgpu::RenderPass<'_>, color: bool) {
        let Some((buffer, count, _)) = &self.vertices else {
            return;
        };
        pass.set_pipeline(if color {
            &self.colored
        } else {
            &self.depth_only
        });
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_vertex_buffer(0, buffer.slice(..));
        pass.draw(0..*count, 0..1);
    }
}

/// What the view owns on the GPU; lives in egui-wgpu's callback resources.
#[derive(Debug)]
pub(crate) struct ViewResources {
    /// The volume renderer (the app sets its volume, TF and budgets).
    pub(crate) renderer: VolumeRenderer,
    /// The four-view layout's axial, coronal and sagittal slice renderers
    /// (the app gives them the volume: in core a copy of the texture each,
    /// out of core the 3D view's `StreamedVolume`).
    pub(crate) slices: [VolumeRenderer; 3],
    overlay: Overlay,
    /// The host-depth texture (screen-sized, sampled by the rays).
    host_depth: Option<(wgpu::Texture, wgpu::TextureView)>,
    /// Whether the last `prepare` succeeded (so `paint` may `render`).
    prepared: bool,
    /// The last error of `prepare` or `render`, for the app to show.
    pub(crate) error: Mutex<Option<String>>,
    /// Prepares recorded (frames drawn by the renderer).
    pub(crate) frames: u64,
}

impl ViewResources {
    /// Creates the renderer and overlay for egui's target format.
    pub(crate) fn new(
        device: &wgpu::Device,
        color_format: wgpu::TextureFormat,
        options: brickray::RendererOptions,
    ) -> Result<ViewResources, brickray::RenderError> {
        let targets = TargetDesc::new(color_format).with_depth(DEPTH_FORMAT);
        let slice = || VolumeRenderer::with_options(device, targets, options);
        Ok(ViewResources {
            renderer: VolumeRenderer::with_options(device, targets, options)?,
            slices: [slice()?, slice()?, slice()?],
            overlay: Overlay::new(device, color_format),
            host_depth: None,
            prepared: false,
            error: Mutex::new(None),
            frames: 0,
        })
    }

    /// Takes the last error.
    pub(crate) fn take_error(&self) -> Option<String> {
        self.error.lock().ok().and_then(|mut e| e.take())
    }

    /// Records a `prepare`'s outcome: a frame drawn, or its error (no
    /// volume yet is not one).
    fn after_prepare<T>(&mut self, result: Result<T, brickray::PrepareError>) {
        match result {
            Ok(_) => {
                self.prepared = true;
                self.frames += 1;
            }
            Err(brickray::PrepareError::NoVolume) => {}
            Err(e) => self.set_error(format!("prepare: {e}")),
        }
    }

    fn set_error(&self, e: String) {
        if let Ok(mut slot) = self.error.lock() {
            *slot = Some(e);
        }
    }

    /// The host-depth texture view, (re)created at the screen's size.
    fn host_depth(
        &mut self,
        device: &wgpu::Device,
        size: [u32; 2],
    ) -> Result<&wgpu::TextureView, String> {
        let limit = device.limits().max_texture_dimension_2d;
        if size[0] > limit || size[1] > limit || size[0] == 0 || size[1] == 0 {
            return Err(format!(
                "the window ({}x{}) exceeds the device's 2D texture limit {limit}",
                size[0], size[1]
            ));
        }
        let fits = self
            .host_depth
            .as_ref()
            .is_some_and(|(t, _)| t.width() == size[0] && t.height() == size[1]);
        if !fits {
            let texture = device.create_texture(&wgpu::TextureDescriptor {
                label: Some("brickray-viewer host depth"),
                size: wgpu::Extent3d {
                    width: size[0],
                    height: size[1],
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: DEPTH_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            });
            let view = texture.create_view(&Default::default());
            self.host_depth = Some((texture, view));
        }
        Ok(&self.host_depth.as_ref().expect("created above").1)
    }
}

/// One frame of the view: what the app decided this frame.
#[derive(Debug, Clone)]
pub(crate) struct VolumeCallback {
    /// The view's rectangle in points.
    pub(crate) rect: egui::Rect,
    /// The camera.
    pub(crate) camera: Camera,
    /// The volume's placement.
    pub(crate) frame: VolumeFrame,
    /// Render settings.
    pub(crate) settings: RenderSettings,
    /// Draw the bounding box and axes.
    pub(crate) overlays: bool,
    /// The frame's time in seconds (egui's clock): level-of-detail fades
    /// advance with it.
    pub(crate) time: f64,
}

/// One frame of the four-view layout: the 3D view and three slices, prepared
/// together (one plan of a streamed volume for all four) and drawn in one
/// paint callback over the central rectangle.
#[derive(Debug, Clone)]
pub(crate) struct FourViewCallback {
    /// The 3D view (its rectangle is the bottom-right quadrant).
    pub(crate) view_3d: VolumeCallback,
    /// The axial, coronal and sagittal slices and their rectangles.
    pub(crate) slices: [(egui::Rect, SliceView); 3],
}

impl egui_wgpu::CallbackTrait for FourViewCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        screen: &egui_wgpu::ScreenDescriptor,
        encoder: &mut wgpu::CommandEncoder,
        resources: &mut egui_wgpu::CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(r) = resources.get_mut::<ViewResources>() else {
            return Vec::new();
        };
        r.prepared = false;
        let px =
            |rect: &egui::Rect| viewport_px(rect, screen.pixels_per_point, screen.size_in_pixels);
        let cb = &self.view_3d;
        let Some(vp) = px(&cb.rect) else {
            return Vec::new();
        };
        let mut descs = vec![FrameDesc {
            camera: cb.camera,
            frame: cb.frame,
            viewport: vp,
            settings: cb.settings,
            host_depth: None,
            time: Some(cb.time),
        }];
        for (i, (rect, slice)) in self.slices.iter().enumerate() {
            let Some(vp) = px(rect) else {
                return Vec::new();
            };
            r.slices[i].set_slice(Some(*slice));
            descs.push(FrameDesc {
                viewport: vp,
                ..descs[0].clone()
            });
        }
        let ViewResources {
            renderer, slices, ..
        } = &mut *r;
        let [a, b, c] = slices;
        let mut views = [
            (renderer, &descs[0]),
            (a, &descs[1]),
            (b, &descs[2]),
            (c, &descs[3]),
        ];
        let result = VolumeRenderer::prepare_views(device, queue, encoder, &mut views);
        r.after_prepare(result);
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        resources: &egui_wgpu::CallbackResources,
    ) {
        let Some(r) = resources.get::<ViewResources>() else {
            return;
        };
        if !r.prepared {
            return;
        }
        for v in std::iter::once(&r.renderer).chain(&r.slices) {
            if let Err(e) = v.render(pass) {
                r.set_error(format!("render: {e}"));
            }
        }
    }
}

/// The viewport in the target's pixels for a rectangle in points (egui's own
/// rounding, so it equals the pass's viewport in `paint`).
pub(crate) fn viewport_px(
    rect: &egui::Rect,
    pixels_per_point: f32,
    screen: [u32; 2],
) -> Option<Viewport> {
    let v = egui::epaint::ViewportInPixels::from_points(rect, pixels_per_point, screen);
    (v.width_px > 0 && v.height_px > 0 && v.left_px >= 0 && v.top_px >= 0).then_some(Viewport {
        x: v.left_px as u32,
        y: v.top_px as u32,
        width: v.width_px as u32,
        height: v.height_px as u32,
    })
}

impl egui_wgpu::CallbackTrait for VolumeCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        screen: &egui_wgpu::ScreenDescriptor,
        encoder: &mut wgpu::CommandEncoder,
        resources: &mut egui_wgpu::CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(r) = resources.get_mut::<ViewResources>() else {
            return Vec::new();
        };
        r.prepared = false;
        let Some(vp) = viewport_px(&self.rect, screen.pixels_per_point, screen.size_in_pixels)
        else {
            return Vec::new();
        };
        let view_proj = self.camera.view_proj(vp.aspect() as f32);
        r.overlay.update(device, queue, &self.frame, view_proj);
        let mut host_depth = None;
        if self.overlays {
            match r.host_depth(device, screen.size_in_pixels) {
                Ok(view) => {
                    // The host's opaque pass: the lines' depth, for the rays.
                    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                        label: Some("brickray-viewer overlay depth"),
                        color_attachments: &[],
                        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                            view,
                            depth_ops: Some(wgpu::Operations {
                                load: wgpu::LoadOp::Clear(self.camera.depth.far_value()),
                                store: wgpu::StoreOp::Store,
                            }),
                            stencil_ops: None,
                        }),
                        ..Default::default()
                    });
                    let (x, y) = (vp.x as f32, vp.y as f32);
                    pass.set_viewport(x, y, vp.width as f32, vp.height as f32, 0.0, 1.0);
                    r.overlay.draw(&mut pass, false);
                    drop(pass);
                }
                Err(e) => r.set_error(e),
            }
            host_depth = r.host_depth.as_ref().map(|(_, v)| v.clone());
        }
        let desc = FrameDesc {
            camera: self.camera,
            frame: self.frame,
            viewport: vp,
            settings: self.settings,
            host_depth: host_depth.as_ref(),
            time: Some(self.time),
        };
        let result = r.renderer.prepare(device, queue, encoder, &desc);
        r.after_prepare(result);
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        resources: &egui_wgpu::CallbackResources,
    ) {
        let Some(r) = resources.get::<ViewResources>() else {
            return;
        };
        if self.overlays {
            r.overlay.draw(pass, true);
        }
        if r.prepared
            && let Err(e) = r.renderer.render(pass)
        {
            r.set_error(format!("render: {e}"));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The overlay shader parses and validates, and its vertex inputs match
    /// [`LineVertex`].
    #[test]
    fn overlay_shader_validates() {
        let src = include_str!("../shaders/overlay.wgsl");
        let module = naga::front::wgsl::parse_str(src).expect("parse");
        naga::valid::Validator::new(Default::default(), naga::valid::Capabilities::empty())
            .validate(&module)
            .expect("validate");
        let vs = module
            .entry_points
            .iter()
            .find(|e| e.name == "vs_main")
            .expect("vs_main");
        assert_eq!(vs.function.arguments.len(), 2);
        assert_eq!(std::mem::size_of::<LineVertex>(), 32);
    }

    #[test]
    fn overlay_lines_outline_the_box() {
        let frame = VolumeFrame::centered([64, 32, 16], [1.0; 3]);
        let v = overlay_lines(&frame);
        assert_eq!(v.len(), 2 * (12 + 3));
        let size = frame.world_size();
        // Box edges have the box's side lengths: four of each.
        let mut lengths: Vec<f32> = v[..24]
            .chunks(2)
            .map(|e| {
                (Vec3::from_slice(&e[0].position[..3]) - Vec3::from_slice(&e[1].position[..3]))
                    .length()
            })
            .collect();
        lengths.sort_by(f32::total_cmp);
        let mut want: Vec<f32> = [size.x, size.y, size.z]
            .iter()
            .flat_map(|&s| [s; 4])
            .collect();
        want.sort_by(f32::total_cmp);
        for (a, b) in lengths.iter().zip(&want) {
            assert!((a - b).abs() < 1e-5, "{lengths:?} vs {want:?}");
        }
    }

    #[test]
    fn viewports_follow_egui_rounding() {
        let r = egui::Rect::from_min_size(egui::pos2(10.3, 20.0), egui::vec2(100.0, 50.0));
        let vp = viewport_px(&r, 2.0, [1000, 1000]).unwrap();
        assert_eq!((vp.x, vp.y, vp.width, vp.height), (21, 40, 200, 100));
        let off = egui::Rect::from_min_size(egui::pos2(2000.0, 0.0), egui::vec2(10.0, 10.0));
        assert!(viewport_px(&off, 1.0, [100, 100]).is_none());
    }
}
