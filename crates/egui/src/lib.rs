//! brickray in egui: out-of-core volume views as egui widgets, drawn through
//! egui-wgpu paint callbacks (egui 0.37, egui-wgpu 0.37, wgpu 30).
//!
//! A host needs three things:
//!
//! 1. **A device and a pass brickray can use.** The device must have
//!    `brickray::required_limits()` (and may have
//!    `brickray::optional_features()`); egui's render pass needs a
//!    [`DEPTH_FORMAT`] depth buffer (in eframe: `NativeOptions::depth_buffer
//!    = 32`), which the volume and the 3D view's bounding box test and write.
//! 2. **One call at start-up**, [`install`], which puts the renderers
//!    ([`ViewResources`]) in egui-wgpu's callback resources; then the host
//!    gives them a volume and a transfer function through [`with_resources`]
//!    (`VolumeRenderer::set_volume`, `set_volume_source`,
//!    `set_transfer_function`, ...).
//! 3. **One line per frame and view**: [`VolumeView`] (a 3D view whose
//!    camera a `CameraController` holds: drag to orbit, right-drag to pan,
//!    wheel to zoom, WASD/QE to fly, R to reset) or [`SliceWidget`] (a slice,
//!    the wheel stepping it).
//!
//! ```no_run
//! use brickray::core::camera::CameraController;
//! use brickray::VolumeFrame;
//!
//! struct App {
//!     controller: CameraController,
//!     frame: VolumeFrame,
//! }
//!
//! impl App {
//!     fn new(render_state: &egui_wgpu::RenderState, volume: &brickray::Volume) -> App {
//!         brickray_egui::install(render_state, Default::default()).expect("brickray renders here");
//!         brickray_egui::with_resources(render_state, |device, queue, r| {
//!             r.renderer.set_volume(device, queue, volume)
//!         })
//!         .expect("installed")
//!         .expect("the volume fits");
//!         let frame = VolumeFrame::centered(volume.dims(), volume.desc().spacing);
//!         App { controller: CameraController::new(&frame), frame }
//!     }
//!
//!     fn ui(&mut self, ui: &mut egui::Ui) {
//!         let settings = brickray::RenderSettings::default();
//!         brickray_egui::VolumeView::new(&mut self.controller, self.frame, settings).show(ui);
//!     }
//! }
//! ```
//!
//! The lower-level pieces are public too: the paint callbacks
//! ([`VolumeCallback`], [`FourViewCallback`]: a 3D view and three slices
//! prepared together, [`SliceCallback`]), the camera mapping
//! ([`camera_input`]) and egui's points-to-pixels rounding
//! ([`viewport_px`]). `brickray-viewer` is built on this crate.

mod callback;
mod overlay;
mod resources;
mod widget;

pub use callback::{FourViewCallback, SliceCallback, VolumeCallback, viewport_px};
pub use overlay::PLANE_COLORS;
pub use resources::ViewResources;
pub use widget::{SliceWidget, VolumeView, VolumeViewOutput, camera_input};

/// The depth format of egui's pass that the views draw in (eframe:
/// `NativeOptions::depth_buffer = 32`), and of the 3D view's host-depth
/// texture.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Creates the renderers ([`ViewResources`]) for egui-wgpu's target format
/// and installs them in its callback resources, replacing any installed
/// before (call it again to change `options`; the new renderers have no
/// volume yet). The device must have `brickray::required_limits()`.
pub fn install(
    render_state: &egui_wgpu::RenderState,
    options: brickray::RendererOptions,
) -> Result<(), brickray::RenderError> {
    let r = ViewResources::new(&render_state.device, render_state.target_format, options)?;
    render_state.renderer.write().callback_resources.insert(r);
    Ok(())
}

/// Runs `f` on the installed [`ViewResources`] with the device and queue
/// (to set the volume, the transfer function, budgets, or read statistics);
/// `None` when [`install`] was not called. Holds egui-wgpu's renderer lock
/// meanwhile: do not call it from inside a paint callback.
pub fn with_resources<R>(
    render_state: &egui_wgpu::RenderState,
    f: impl FnOnce(&wgpu::Device, &wgpu::Queue, &mut ViewResources) -> R,
) -> Option<R> {
    let mut renderer = render_state.renderer.write();
    let r = renderer.callback_resources.get_mut::<ViewResources>()?;
    Some(f(&render_state.device, &render_state.queue, r))
}
