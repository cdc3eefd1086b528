//! The paint callbacks: brickray drawn into egui's frame through
//! egui-wgpu's `CallbackTrait`, the way any host embeds it. egui's render
//! pass is the host's pass (its colour target and a [`DEPTH_FORMAT`] depth
//! buffer), the callback's rectangle is the viewport, and the 3D view's own
//! geometry (the bounding box and axes) composites with the volume by depth
//! in both directions:
//!
//! 1. `prepare` (egui's encoder): a depth-only pass draws the lines into the
//!    host-depth texture, then `VolumeRenderer::prepare` records the ray
//!    cast, whose rays stop at that depth;
//! 2. `paint` (egui's pass): the lines are drawn with colour and depth, then
//!    `VolumeRenderer::render` blends the volume over them and writes depth.

#[cfg(doc)]
use crate::DEPTH_FORMAT;
use crate::ViewResources;
use crate::overlay::{PLANE_COLORS, PlaneOutline};
use brickray::{
    Camera, FrameDesc, RenderSettings, SliceView, Viewport, VolumeFrame, VolumeRenderer,
};
use egui_wgpu::{CallbackResources, CallbackTrait, ScreenDescriptor};

/// One frame of a 3D view: the paint callback that draws
/// [`ViewResources::renderer`] in `rect` (add it with
/// `egui_wgpu::Callback::new_paint_callback(rect, callback)`;
/// [`crate::VolumeView`] does).
#[derive(Debug, Clone)]
pub struct VolumeCallback {
    /// The view's rectangle in points.
    pub rect: egui::Rect,
    /// The camera.
    pub camera: Camera,
    /// The volume's placement.
    pub frame: VolumeFrame,
    /// Render settings.
    pub settings: RenderSettings,
    /// Draw the bounding box and axes (depth-composited with the volume).
    pub overlays: bool,
    /// The frame's time in seconds (egui's clock, `InputState::time`):
    /// level-of-detail fades advance with it.
    pub time: f64,
}

/// One frame of the four-view layout: the 3D view and three slices, prepared
/// together (one plan of a streamed volume for all four, through
/// `VolumeRenderer::prepare_views`) and drawn in one paint callback (add it
/// over the rectangle that holds the four). The 3D view is drawn by
/// [`ViewResources::renderer`], the slices by
/// [`ViewResources::slices`] in order.
#[derive(Debug, Clone)]
pub struct FourViewCallback {
    /// The 3D view (its `rect` is its quadrant; with `overlays`, its box and
    /// axes and the outlines of the slices normal to an index axis, in
    /// [`crate::PLANE_COLORS`]).
    pub view_3d: VolumeCallback,
    /// The slices for [`ViewResources::slices`] 0, 1 and 2, and their
    /// rectangles in points.
    pub slices: [(egui::Rect, SliceView); 3],
}

/// One frame of a slice view: the paint callback that draws
/// `ViewResources::slices[slot]` showing `slice` in `rect`
/// ([`crate::SliceWidget`] adds it).
#[derive(Debug, Clone)]
pub struct SliceCallback {
    /// The view's rectangle in points.
    pub rect: egui::Rect,
    /// Which of [`ViewResources::slices`] draws it (0, 1 or 2; others draw
    /// nothing).
    pub slot: usize,
    /// The slice.
    pub slice: SliceView,
    /// The volume's placement.
    pub frame: VolumeFrame,
    /// Render settings (the slice uses the sampling settings; mode and
    /// shading are the 3D view's).
    pub settings: RenderSettings,
    /// The frame's time in seconds (egui's clock).
    pub time: f64,
}

/// The viewport in the target's pixels for a rectangle in points, with
/// egui's own rounding (so it equals the pass's viewport in a paint
/// callback's `paint`); `None` when it is empty or starts off the target.
pub fn viewport_px(rect: &egui::Rect, pixels_per_point: f32, screen: [u32; 2]) -> Option<Viewport> {
    let v = egui::epaint::ViewportInPixels::from_points(rect, pixels_per_point, screen);
    (v.width_px > 0 && v.height_px > 0 && v.left_px >= 0 && v.top_px >= 0).then_some(Viewport {
        x: v.left_px as u32,
        y: v.top_px as u32,
        width: v.width_px as u32,
        height: v.height_px as u32,
    })
}

impl CallbackTrait for FourViewCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        screen: &ScreenDescriptor,
        encoder: &mut wgpu::CommandEncoder,
        resources: &mut CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(r) = resources.get_mut::<ViewResources>() else {
            return Vec::new();
        };
        r.unprepare(0..4);
        let px =
            |rect: &egui::Rect| viewport_px(rect, screen.pixels_per_point, screen.size_in_pixels);
        let cb = &self.view_3d;
        let Some(vp) = px(&cb.rect) else {
            return Vec::new();
        };
        // With overlays, the box and the slices' planes in the 3D view.
        let host_depth = if cb.overlays {
            let planes: Vec<PlaneOutline> = self
                .slices
                .iter()
                .zip(PLANE_COLORS)
                .filter_map(|((_, s), c)| PlaneOutline::of(s, &cb.frame, c))
                .collect();
            overlay_depth(r, device, queue, encoder, screen, vp, cb, &planes)
        } else {
            None
        };
        let mut descs = vec![FrameDesc {
            camera: cb.camera,
            frame: cb.frame,
            viewport: vp,
            settings: cb.settings,
            host_depth: host_depth.as_ref(),
            time: Some(cb.time),
        }];
        for (i, (rect, slice)) in self.slices.iter().enumerate() {
            let Some(vp) = px(rect) else {
                return Vec::new();
            };
            r.slices[i].set_slice(Some(*slice));
            descs.push(FrameDesc {
                viewport: vp,
                host_depth: None,
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
        r.after_prepare(0..4, result);
        Vec::new()
    }

    fn paint(
        &self,
        info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        resources: &CallbackResources,
    ) {
        let Some(r) = resources.get::<ViewResources>() else {
            return;
        };
        if self.view_3d.overlays
            && let Some(vp) = viewport_px(
                &self.view_3d.rect,
                info.pixels_per_point,
                info.screen_size_px,
            )
        {
            pass.set_viewport(
                vp.x as f32,
                vp.y as f32,
                vp.width as f32,
                vp.height as f32,
                0.0,
                1.0,
            );
            r.overlay().draw(pass, true);
        }
        for i in (0..4).filter(|&i| r.is_prepared(i)) {
            if let Err(e) = r.renderer_at(i).render(pass) {
                r.set_error(format!("render: {e}"));
            }
        }
    }
}

/// The 3D view's overlay lines (the box, the axes and `planes`) for
/// `view` in viewport `vp`: their view-projection and vertices updated, and
/// their depth drawn into the host depth the rays test against (the host's
/// opaque pass); that depth, or `None` (the error recorded).
#[allow(clippy::too_many_arguments)]
fn overlay_depth(
    r: &mut ViewResources,
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    encoder: &mut wgpu::CommandEncoder,
    screen: &ScreenDescriptor,
    vp: Viewport,
    view: &VolumeCallback,
    planes: &[PlaneOutline],
) -> Option<wgpu::TextureView> {
    let view_proj = view.camera.view_proj(vp.aspect() as f32);
    r.overlay_mut()
        .update(device, queue, &view.frame, planes, view_proj);
    let depth = match r.host_depth(device, screen.size_in_pixels) {
        Ok(depth) => depth.clone(),
        Err(e) => {
            r.set_error(e);
            return None;
        }
    };
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("brickray-egui overlay depth"),
        color_attachments: &[],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: &depth,
            depth_ops: Some(wgpu::Operations {
                load: wgpu::LoadOp::Clear(view.camera.depth.far_value()),
                store: wgpu::StoreOp::Store,
            }),
            stencil_ops: None,
        }),
        ..Default::default()
    });
    let (x, y) = (vp.x as f32, vp.y as f32);
    pass.set_viewport(x, y, vp.width as f32, vp.height as f32, 0.0, 1.0);
    r.overlay().draw(&mut pass, false);
    drop(pass);
    r.host_depth_view().cloned()
}

impl CallbackTrait for VolumeCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        screen: &ScreenDescriptor,
        encoder: &mut wgpu::CommandEncoder,
        resources: &mut CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(r) = resources.get_mut::<ViewResources>() else {
            return Vec::new();
        };
        r.unprepare(0..1);
        let Some(vp) = viewport_px(&self.rect, screen.pixels_per_point, screen.size_in_pixels)
        else {
            return Vec::new();
        };
        let host_depth = self
            .overlays
            .then(|| overlay_depth(r, device, queue, encoder, screen, vp, self, &[]));
        let host_depth = host_depth.flatten();
        let desc = FrameDesc {
            camera: self.camera,
            frame: self.frame,
            viewport: vp,
            settings: self.settings,
            host_depth: host_depth.as_ref(),
            time: Some(self.time),
        };
        let result = r.renderer.prepare(device, queue, encoder, &desc);
        r.after_prepare(0..1, result);
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        resources: &CallbackResources,
    ) {
        let Some(r) = resources.get::<ViewResources>() else {
            return;
        };
        if self.overlays {
            r.overlay().draw(pass, true);
        }
        if r.is_prepared(0)
            && let Err(e) = r.renderer.render(pass)
        {
            r.set_error(format!("render: {e}"));
        }
    }
}

impl CallbackTrait for SliceCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        screen: &ScreenDescriptor,
        encoder: &mut wgpu::CommandEncoder,
        resources: &mut CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(r) = resources.get_mut::<ViewResources>() else {
            return Vec::new();
        };
        let Some(renderer) = r.slices.get_mut(self.slot) else {
            return Vec::new();
        };
        renderer.set_slice(Some(self.slice));
        let i = self.slot + 1;
        r.unprepare(i..i + 1);
        let Some(vp) = viewport_px(&self.rect, screen.pixels_per_point, screen.size_in_pixels)
        else {
            return Vec::new();
        };
        // The renderer draws the slice with the slice's own camera; a frame
        // still needs a valid one.
        let camera = match self.slice.resolve(&self.frame, vp.aspect()) {
            Ok(g) => g.camera(),
            Err(e) => {
                r.set_error(format!("slice: {e}"));
                return Vec::new();
            }
        };
        let desc = FrameDesc {
            camera,
            frame: self.frame,
            viewport: vp,
            settings: self.settings,
            host_depth: None,
            time: Some(self.time),
        };
        let result = r.slices[self.slot].prepare(device, queue, encoder, &desc);
        r.after_prepare(i..i + 1, result);
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        resources: &CallbackResources,
    ) {
        let Some(r) = resources.get::<ViewResources>() else {
            return;
        };
        let i = self.slot + 1;
        if i < 4
            && r.is_prepared(i)
            && let Err(e) = r.renderer_at(i).render(pass)
        {
            r.set_error(format!("render: {e}"));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viewports_follow_egui_rounding() {
        let r = egui::Rect::from_min_size(egui::pos2(10.3, 20.0), egui::vec2(100.0, 50.0));
        let vp = viewport_px(&r, 2.0, [1000, 1000]).unwrap();
        assert_eq!((vp.x, vp.y, vp.width, vp.height), (21, 40, 200, 100));
        let off = egui::Rect::from_min_size(egui::pos2(2000.0, 0.0), egui::vec2(10.0, 10.0));
        assert!(viewport_px(&off, 1.0, [100, 100]).is_none());
    }
}
