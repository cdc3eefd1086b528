//! The GPU side of the views: the renderers, the overlay and the host-depth
//! texture, kept in egui-wgpu's `CallbackResources`.

use crate::DEPTH_FORMAT;
use crate::overlay::Overlay;
use brickray::{TargetDesc, VolumeRenderer};
use std::sync::Mutex;

/// What the views own on the GPU: one 3D renderer, three slice renderers,
/// the bounding-box overlay and the host-depth texture. [`crate::install`]
/// puts it in egui-wgpu's `CallbackResources`, where every paint callback of
/// this crate finds it; the host reaches it through
/// [`crate::with_resources`] to give the renderers their volume, transfer
/// function, budgets and so on.
#[derive(Debug)]
pub struct ViewResources {
    /// The 3D view's renderer ([`crate::VolumeView`], [`crate::VolumeCallback`],
    /// the 3D quadrant of [`crate::FourViewCallback`]). The host sets its
    /// volume, transfer function and budgets.
    pub renderer: VolumeRenderer,
    /// The slice renderers ([`crate::SliceWidget`]'s slots 0, 1 and 2, and
    /// the four-view layout's axial, coronal and sagittal slices). The host
    /// gives them the volume: in core a copy of the texture each
    /// (`VolumeRenderer::set_volume`), out of core the 3D renderer's
    /// `StreamedVolume` (`VolumeRenderer::set_streamed_volume`).
    pub slices: [VolumeRenderer; 3],
    overlay: Overlay,
    /// The host-depth texture (screen-sized, sampled by the rays).
    host_depth: Option<(wgpu::Texture, wgpu::TextureView)>,
    /// Whether the last `prepare` of the 3D renderer (0) and of each slice
    /// renderer (1..=3) succeeded, so that `paint` may `render` it.
    prepared: [bool; 4],
    /// The last error of `prepare` or `render`.
    error: Mutex<Option<String>>,
    /// Prepares recorded.
    frames: u64,
}

impl ViewResources {
    /// Creates the renderers and the overlay for a colour target of
    /// `color_format` with a [`DEPTH_FORMAT`] depth buffer (egui's pass).
    /// [`crate::install`] calls this with egui-wgpu's target format.
    pub fn new(
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
            prepared: [false; 4],
            error: Mutex::new(None),
            frames: 0,
        })
    }

    /// Takes the last error of a paint callback's `prepare` or `render` (a
    /// paint callback cannot return one), to show or log; `None` when there
    /// was none since the last call. No volume yet is not an error.
    pub fn take_error(&self) -> Option<String> {
        self.error.lock().ok().and_then(|mut e| e.take())
    }

    /// How many `prepare`s succeeded so far (a four-view layout's counts
    /// once): frames drawn, for frame statistics.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Records a `prepare`'s outcome for the renderers `which` (indices into
    /// `prepared`): a frame drawn, or its error (no volume yet is not one).
    pub(crate) fn after_prepare<T>(
        &mut self,
        which: std::ops::Range<usize>,
        result: Result<T, brickray::PrepareError>,
    ) {
        match result {
            Ok(_) => {
                self.prepared[which].fill(true);
                self.frames += 1;
            }
            Err(brickray::PrepareError::NoVolume) => {}
            Err(e) => self.set_error(format!("prepare: {e}")),
        }
    }

    /// Marks the renderers `which` as not prepared (before a `prepare`).
    pub(crate) fn unprepare(&mut self, which: std::ops::Range<usize>) {
        self.prepared[which].fill(false);
    }

    /// Whether renderer `i` (0: 3D, 1..=3: the slices) may `render`.
    pub(crate) fn is_prepared(&self, i: usize) -> bool {
        self.prepared[i]
    }

    /// The renderer of index `i` (0: 3D, 1..=3: the slices).
    pub(crate) fn renderer_at(&self, i: usize) -> &VolumeRenderer {
        match i {
            0 => &self.renderer,
            i => &self.slices[i - 1],
        }
    }

    pub(crate) fn overlay(&self) -> &Overlay {
        &self.overlay
    }

    pub(crate) fn overlay_mut(&mut self) -> &mut Overlay {
        &mut self.overlay
    }

    pub(crate) fn host_depth_view(&self) -> Option<&wgpu::TextureView> {
        self.host_depth.as_ref().map(|(_, v)| v)
    }

    pub(crate) fn set_error(&self, e: String) {
        if let Ok(mut slot) = self.error.lock() {
            *slot = Some(e);
        }
    }

    /// The host-depth texture view, (re)created at the screen's size.
    pub(crate) fn host_depth(
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
                label: Some("brickray-egui host depth"),
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
