//! The 3D view's own geometry: the volume's bounding box and axes, drawn as
//! depth-tested lines in world space (a depth-only pass in `prepare` gives
//! the rays the lines' depth; the same lines drawn in egui's pass get the
//! colour).

use crate::DEPTH_FORMAT;
use brickray::VolumeFrame;
use glam::{Mat4, Vec3};

/// A line vertex: position (w unused) and colour.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct LineVertex {
    position: [f32; 4],
    color: [f32; 4],
}

/// The colours of the slice planes' outlines in the 3D view of the
/// four-view layout (slot 0, 1, 2: axial, coronal, sagittal, after 3D
/// Slicer's red and green; the third is blue, not Slicer's yellow, which is
/// the crosshair's colour here).
pub const PLANE_COLORS: [[f32; 4]; 3] = [
    [0.95, 0.3, 0.25, 1.0],
    [0.35, 0.85, 0.35, 1.0],
    [0.35, 0.55, 1.0, 1.0],
];

/// A slice plane to outline in the 3D view: the index axis it is normal to
/// and its position along that axis in texture coordinates (0..1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PlaneOutline {
    pub(crate) axis: usize,
    pub(crate) t: f32,
    pub(crate) color: [f32; 4],
}

impl PlaneOutline {
    /// The outline of `slice` of a volume placed by `frame`, when the slice
    /// is normal to an index axis (its right and up lie along the other two;
    /// an oblique plane has no outline here).
    pub(crate) fn of(
        slice: &brickray::SliceView,
        frame: &VolumeFrame,
        color: [f32; 4],
    ) -> Option<PlaneOutline> {
        let axis = (0..3).find(|&a| slice.right[a] == 0.0 && slice.up[a] == 0.0)?;
        let n = frame.dims[axis].max(1) as f64;
        let t = ((slice.centre[axis] + 0.5) / n) as f32;
        (t.is_finite() && (0.0..=1.0).contains(&t)).then_some(PlaneOutline { axis, t, color })
    }
}

/// The bounding box's 12 edges, three axes from the volume's origin corner
/// (x red, y green, z blue) and the outlines of `planes`, in world space.
pub(crate) fn overlay_lines(frame: &VolumeFrame, planes: &[PlaneOutline]) -> Vec<LineVertex> {
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
    for p in planes {
        // The plane's four corners in texture space, in order round it.
        let (a, b) = ((p.axis + 1) % 3, (p.axis + 2) % 3);
        let corner = |i: usize| {
            let mut c = Vec3::ZERO;
            c[p.axis] = p.t;
            c[a] = [0.0, 1.0, 1.0, 0.0][i];
            c[b] = [0.0, 0.0, 1.0, 1.0][i];
            frame.model.transform_point3(c)
        };
        for i in 0..4 {
            line(corner(i), corner((i + 1) % 4), p.color);
        }
    }
    v
}

/// The GPU side of the overlay lines.
#[derive(Debug)]
pub(crate) struct Overlay {
    depth_only: wgpu::RenderPipeline,
    colored: wgpu::RenderPipeline,
    uniforms: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    vertices: Option<(wgpu::Buffer, u32, VolumeFrame, Vec<PlaneOutline>)>,
    view_proj: Option<Mat4>,
}

impl Overlay {
    pub(crate) fn new(device: &wgpu::Device, color_format: wgpu::TextureFormat) -> Overlay {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("brickray-egui overlay.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../shaders/overlay.wgsl").into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("brickray-egui overlay"),
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
            label: Some("brickray-egui overlay"),
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
                    "brickray-egui overlay"
                } else {
                    "brickray-egui overlay depth"
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
            label: Some("brickray-egui overlay uniforms"),
            size: 64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("brickray-egui overlay"),
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

    /// Writes the view-projection and (when the volume or the planes moved)
    /// the lines.
    pub(crate) fn update(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        frame: &VolumeFrame,
        planes: &[PlaneOutline],
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
        if self
            .vertices
            .as_ref()
            .is_some_and(|v| v.2 == *frame && v.3 == planes)
        {
            return;
        }
        let lines = overlay_lines(frame, planes);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("brickray-egui overlay lines"),
            size: std::mem::size_of_val(lines.as_slice()) as u64,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        queue.write_buffer(&buffer, 0, bytemuck::cast_slice(&lines));
        self.vertices = Some((buffer, lines.len() as u32, *frame, planes.to_vec()));
    }

    pub(crate) fn draw(&self, pass: &mut wgpu::RenderPass<'_>, color: bool) {
        let Some((buffer, count, ..)) = &self.vertices else {
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

#[cfg(test)]
mod tests {
    use super::*;
    use brickray::VolumeFrame;

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
        let v = overlay_lines(&frame, &[]);
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

    /// An axial slice through index 12 of 16 is outlined at 12.5/16 of the
    /// box along z, spanning the box in x and y; an oblique one is not.
    #[test]
    fn slice_planes_are_outlined_where_they_cut_the_box() {
        let frame = VolumeFrame::centered([64, 32, 16], [1.0; 3]);
        let axial =
            brickray::SliceView::orthogonal(brickray::SliceAxis::Axial, 12.0, &frame, 1.0).unwrap();
        let p = PlaneOutline::of(&axial, &frame, PLANE_COLORS[0]).unwrap();
        assert_eq!((p.axis, p.t), (2, 12.5 / 16.0));
        let v = overlay_lines(&frame, &[p]);
        assert_eq!(v.len(), 2 * (12 + 3 + 4));
        let size = frame.world_size();
        let z = frame.model.transform_point3(Vec3::new(0.0, 0.0, p.t)).z;
        for e in v[30..].chunks(2) {
            let (a, b) = (
                Vec3::from_slice(&e[0].position[..3]),
                Vec3::from_slice(&e[1].position[..3]),
            );
            assert!((a.z - z).abs() < 1e-6 && (b.z - z).abs() < 1e-6);
            let len = (a - b).length();
            assert!(
                (len - size.x).abs() < 1e-5 || (len - size.y).abs() < 1e-5,
                "{len}"
            );
            assert_eq!(e[0].color, PLANE_COLORS[0]);
        }
        let oblique = brickray::SliceView::with_normal([8.0; 3], [1.0, 1.0, 0.0], 1.0).unwrap();
        assert_eq!(PlaneOutline::of(&oblique, &frame, PLANE_COLORS[1]), None);
    }
}
