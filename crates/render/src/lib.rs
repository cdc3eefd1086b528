//! The wgpu ray caster of brickray and its [`VolumeRenderer`] API.
//!
//! `VolumeRenderer` is middleware in the style of glyphon and egui-wgpu: it takes a
//! `&wgpu::Device`, a `&wgpu::Queue` and the host's target formats; it never
//! requests an adapter, never submits, and never waits on the GPU.
//!
//! Per frame:
//! 1. The host draws its opaque geometry (its depth is then what rays stop at).
//! 2. [`VolumeRenderer::prepare`] writes uniforms and uploads, and records the
//!    ray-cast compute pass into the host's command encoder.
//! 3. In a later render pass that loads the host's colour and depth,
//!    [`VolumeRenderer::render`] records one draw: it blends the premultiplied
//!    volume colour over the host's and writes depth, so geometry drawn later
//!    composites correctly too.
//!
//! The renderer is a thin coordinator of owners, one per GPU object family:
//! `frame.rs` (group 0: frame uniforms, host depth, per-viewport outputs), `tf.rs`
//! (group 1: the transfer function), a volume backend (group 2: in core, one 3D
//! texture; out of core, a brick atlas, its tables and the index), `overlay.rs`
//! (group 3: a label map over the image, or a one-texel stand-in), `kernels.rs`
//! (shader modules and specialised pipelines) and `composite.rs` (the draw into the
//! host's pass); `prepare.rs` records a frame through them. The ray-casting model is specified in `docs/rendering-model.md`;
//! the CPU reference in `brickray-reference` implements it and is the accuracy
//! oracle. The device limits the library needs are [`required_limits`].

mod backend;
mod composite;
mod desc;
mod encoding;
mod error;
mod frame;
mod gpu;
mod group2;
mod kernels;
mod limits;
mod overlay;
mod pick;
mod planner;
mod predict;
mod prepare;
pub mod shaders;
mod slice;
mod tf;
mod timestamps;
mod volume;

pub use backend::{FeedbackStats, OcclusionStats};
/// Budgets, LOD metric and tolerance, fades, retry, visibility policy and its
/// settings, loader threads and floor of the out-of-core path: the cache's own
/// configuration, one value ([`StreamedVolume::configure`]).
pub use brickray_cache::OutOfCoreConfig;
pub use brickray_cache::{
    ConfigError, FadeDuration, Lookahead, RetryPolicy, StreamError, UsageFrame,
};
pub use brickray_visibility::{VisibilityConfig, VisibilityCounts, VisibilityPolicy};
pub use desc::{FrameDesc, FrameStats, OutOfCoreStats, RendererStats, TargetDesc, Viewport};
pub use encoding::U8Filtering;
pub use error::{GpuErrorKind, HostDepthError, PrepareError, RenderError};
pub use frame::PredictionFrame;
pub use limits::{OPTIONAL_FEATURES, OptionalFeature, optional_features, required_limits};
pub use pick::{MAX_PICKS, Pick, PickPoint};
pub use predict::{Prediction, PredictionCounts, PredictionError, TraversalClass};
pub use timestamps::PassTimestamps;

pub use backend::gradients::GradientSource;
/// Slice views and the intensity window (GPU-free, from `brickray-core`).
pub use brickray_core::{
    ColorMap, CtPreset, Intensity, Slab, SlabMode, SliceAxis, SliceError, SliceGeometry, SliceView,
    Window, WindowError,
};
pub use volume::{KeepGradients, StreamedVolume, VolumeOptions};

use backend::{Backend, InCore, OutOfCore};
use brickray_core::{
    BrickSource, ChannelStyle, ChannelVolume, DepthConvention, LabelOverlay, LabelTable,
    OverlayStyle, TransferFunction, Volume,
};
use composite::Compositor;
use frame::FrameState;
use kernels::Kernels;
use slice::FrameMapping;
use std::sync::Arc;
use tf::TfTables;

/// Options fixed for a renderer's lifetime.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RendererOptions {
    /// How u8 volumes are stored and filtered (default: exactly, as the rendering
    /// model says; see `docs/rendering-model.md` for the measured cost).
    pub u8_filtering: U8Filtering,
    /// Streamed volumes made by [`VolumeRenderer::set_volume_source`] plan in
    /// the background ([`VolumeOptions::background_planning`]; default off).
    pub background_planning: bool,
    /// How shaded DVR of a volume in core takes its gradients (default:
    /// precomputed per voxel, [`GradientSource::Precomputed`]; out of core,
    /// [`VolumeOptions::gradients`]).
    pub gradients: GradientSource,
    /// When MIP skips empty space (default: where the volume's macro cells,
    /// or out of core the cut's bricks, say it pays, [`SkipRule::WherePays`]).
    pub mip_skipping: SkipRule,
    /// When DVR skips empty space (default: in core where enough of the
    /// volume's macro cells are transparent through the transfer function,
    /// out of core where enough of the sub-cells of the bricks the frame
    /// draws are, [`SkipRule::WherePays`]; label maps always skip the cells
    /// of hidden labels).
    pub dvr_skipping: SkipRule,
}

/// When a mode uses empty-space skipping (with `Accel::empty_space_skipping`
/// on; off, it never does): [`RendererOptions::mip_skipping`] and
/// [`RendererOptions::dvr_skipping`]. The image is the same either way.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum SkipRule {
    /// DVR in core: where at least [`brickray_core::DVR_SKIP_SHARE_MIN`]
    /// (shaded, [`brickray_core::DVR_SHADED_SKIP_SHARE_MIN`]) of
    /// the macro cells are transparent through the frame's transfer
    /// function (counted when it changes, with the skip distances). Out of
    /// core, each frame a plan is applied, where at least
    /// [`brickray_core::DVR_SKIP_SHARE_MIN_BRICKS`] (shaded,
    /// [`brickray_core::DVR_SHADED_SKIP_SHARE_MIN_BRICKS`]) of the sub-cells
    /// of the bricks the frame draws are transparent through it
    /// (`OutOfCoreStats::dvr_transparent_share`; a multi-channel volume and
    /// a label map always skip). Below, skipping cost up to 1.34x the frame
    /// on lavapipe.
    ///
    /// MIP in core, where the volume's macro cells make at least
    /// [`brickray_core::MIP_SKIP_SHARE_MIN`] of the cells certain to be
    /// skipped (`brickray_core::mip_skipping_pays`, counted at set-up); out
    /// of core, each frame, where the sub-cells of the bricks the frame
    /// draws make at least [`brickray_core::MIP_SKIP_SHARE_MIN_BRICKS`] of
    /// them certain to be skipped within their brick
    /// (`brickray_core::mip_skip_counts`; a multi-channel volume always
    /// skips). Below, skipping cost 1.03-2x the frame on lavapipe.
    ///
    /// Each threshold is taken at the frame's step
    /// ([`brickray_core::ShareByStep`]): a coarser step saves fewer samples
    /// per cell tested, so every rule but DVR's in core asks for more.
    #[default]
    WherePays,
    /// Whenever the settings ask for it.
    Always,
}

/// What `render` needs from the last `prepare`.
#[derive(Debug, Clone, Copy)]
struct Prepared {
    viewport: Viewport,
    convention: DepthConvention,
}

/// The volume renderer. See the crate docs for the frame protocol.
#[derive(Debug)]
pub struct VolumeRenderer {
    targets: TargetDesc,
    options: RendererOptions,
    frame: FrameState,
    tf: TfTables,
    kernels: Kernels,
    compositor: Compositor,
    backend: Option<Backend>,
    prepared: Option<Prepared>,
    last_frame: FrameStats,
    /// The isosurface prediction buffer's settings, when on.
    prediction: Option<Prediction>,
    /// Counts the volumes set (the prediction history is the volume's).
    volume_epoch: u64,
    /// The voxel dims of the volume drawn (a frame must place these).
    volume_dims: Option<[u32; 3]>,
    /// The raw value range of the volume drawn (the window maps through it).
    value_range: [f32; 2],
    /// The slice view drawn instead of the 3D view ([`Self::set_slice`]).
    slice: Option<SliceView>,
    /// The intensity window of MIP and slices ([`Self::set_intensity`]).
    intensity: Option<Intensity>,
    /// The frame being prepared's intensity mapping and slice.
    mapping: Option<FrameMapping>,
    /// Pixels to pick and their read-back ([`Self::request_picks`]).
    picker: pick::Picker,
    /// A label map over the image ([`Self::set_overlay`]; group 3).
    overlay: overlay::OverlayState,
    /// The styles of a multi-channel volume's channels
    /// ([`Self::set_channel_styles`]) and their generation.
    channel_styles: Option<(Vec<ChannelStyle>, u64)>,
    /// Where the ray-cast pass writes its timestamps
    /// ([`Self::set_pass_timestamps`]).
    pass_timestamps: Option<PassTimestamps>,
}

impl VolumeRenderer {
    /// A renderer for the host's targets, with default options.
    pub fn new(device: &wgpu::Device, targets: TargetDesc) -> Result<VolumeRenderer, RenderError> {
        VolumeRenderer::with_options(device, targets, RendererOptions::default())
    }

    /// A renderer for the host's targets. Checks the device's backend
    /// ([`RenderError::UnsupportedBackend`] on OpenGL), its limits and the
    /// targets first; creates no GPU object on failure.
    pub fn with_options(
        device: &wgpu::Device,
        targets: TargetDesc,
        options: RendererOptions,
    ) -> Result<VolumeRenderer, RenderError> {
        kernels::check_backend(device.adapter_info().backend)?;
        kernels::check_limits(device)?;
        composite::check_targets(device, &targets)?;
        Ok(VolumeRenderer {
            targets,
            options,
            frame: FrameState::new(device)?,
            picker: pick::Picker::new(device)?,
            overlay: overlay::OverlayState::new(device)?,
            tf: TfTables::new(device)?,
            kernels: Kernels::default(),
            compositor: Compositor::new(device, &targets)?,
            backend: None,
            prepared: None,
            last_frame: FrameStats::default(),
            prediction: None,
            volume_epoch: 0,
            volume_dims: None,
            value_range: [0.0, 1.0],
            slice: None,
            intensity: None,
            mapping: None,
            channel_styles: None,
            pass_timestamps: None,
        })
    }

    /// The targets this renderer draws into.
    pub fn targets(&self) -> TargetDesc {
        self.targets
    }

    /// Uploads a volume into one 3D texture (the in-core path) and builds its
    /// macro-cell grid. Fails with [`RenderError::VolumeTooLarge`] when a dimension
    /// exceeds the device's 3D texture limit, and with
    /// [`RenderError::BadValueRange`] when its value range is not finite.
    pub fn set_volume(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        volume: &Volume,
    ) -> Result<(), RenderError> {
        check_value_range(volume.desc().value_range)?;
        // Free the old volume first: two large volumes need not fit at once.
        self.drop_volume();
        let b = InCore::new(
            device,
            queue,
            volume,
            self.options.u8_filtering,
            self.options.gradients == GradientSource::Precomputed,
            self.options.mip_skipping,
            self.options.dvr_skipping,
        )?;
        self.backend = Some(Backend::InCore(Box::new(b)));
        self.volume_dims = Some(volume.dims());
        self.value_range = volume.desc().value_range;
        Ok(())
    }

    /// Uploads a multi-channel volume (1 to 4 intensity channels on one
    /// grid, [`ChannelVolume`]) into one 3D texture, its channels packed in
    /// each texel (RG or RGBA of the dtype's format, filtered by the
    /// hardware), with each channel's macro-cell ranges. Its channels are
    /// drawn through [`Self::set_channel_styles`] (one transfer function,
    /// visibility and isovalue per channel) and composited in one ray:
    /// DVR mixes the visible channels' samples, MIP each channel's maximum,
    /// iso finds the first crossing of any channel's own isovalue
    /// ([`brickray_core::channels`]); slice views add the visible channels'
    /// colours ([`brickray_core::channels::slice_color`]; the intensity
    /// window is not used). A label map over the channels
    /// ([`Self::set_overlay`]) colours or masks every channel's samples as it
    /// does a single channel's; pre-integration and the prediction buffer
    /// are not used with channels. Fails as [`Self::set_volume`] does, per
    /// channel.
    pub fn set_channel_volume(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        volume: &ChannelVolume,
    ) -> Result<(), RenderError> {
        for v in volume.channels() {
            check_value_range(v.desc().value_range)?;
        }
        self.drop_volume();
        let b = backend::Channels::new(device, queue, volume, self.options.u8_filtering)?;
        self.backend = Some(Backend::Channels(Box::new(b)));
        self.volume_dims = Some(volume.dims());
        self.value_range = volume.desc().value_range;
        Ok(())
    }

    /// Sets how each channel of a multi-channel volume is drawn: one style
    /// per channel, in order (its transfer function, visibility and
    /// isovalue; [`ChannelStyle::window`] makes one from a colour and a
    /// window). Checked against the channel volume set, if any
    /// ([`ChannelError::StyleCount`](brickray_core::ChannelError)), and again
    /// at `prepare`; uploaded there, when they changed.
    pub fn set_channel_styles(&mut self, styles: &[ChannelStyle]) -> Result<(), RenderError> {
        if let Some(n) = self.backend.as_ref().and_then(Backend::channel_count) {
            brickray_core::channels::validate_styles(styles, n)?;
        }
        if self
            .channel_styles
            .as_ref()
            .is_some_and(|(s, _)| s == styles)
        {
            return Ok(());
        }
        self.channel_styles = Some((styles.to_vec(), tf::next_generation()));
        Ok(())
    }

    /// The channel styles set last.
    pub fn channel_styles(&self) -> Option<&[ChannelStyle]> {
        self.channel_styles.as_ref().map(|(s, _)| s.as_slice())
    }

    /// Switches to the out-of-core path over a brick source (a brick-octree file
    /// store, an OME-Zarr image or a procedural source): bricks stream in
    /// asynchronously, a coarse image appears at once and sharpens over frames.
    /// A convenience for a volume only this renderer draws: it creates a
    /// [`StreamedVolume`] with `config` and this renderer's texel options and
    /// draws it ([`Self::streamed_volume`] hands it out, to configure it or to
    /// give it to another renderer). Blocks on the source at most
    /// `config.setup_deadline` ([`StreamedVolume::new`]).
    pub fn set_volume_source(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        source: Arc<dyn BrickSource>,
        config: OutOfCoreConfig,
    ) -> Result<(), RenderError> {
        check_value_range(source.layout().volume.value_range)?;
        // Free the old volume first: two large volumes need not fit at once.
        self.drop_volume();
        // (Gradients out of core are kept where the budget holds every
        // brick with them: `KeepGradients::WhenEveryBrickFits`.)
        let options = VolumeOptions {
            u8_filtering: self.options.u8_filtering,
            background_planning: self.options.background_planning,
            ..Default::default()
        };
        let v = StreamedVolume::new(device, queue, source, config, options)?;
        self.set_streamed_volume(device, &v)
    }

    /// Draws a streamed volume the host owns, which other renderers may draw
    /// too (a stereo pair, a 3D view beside an orthogonal view): views of one
    /// volume prepared together ([`Self::prepare_views`]) refine one cut that
    /// satisfies all of them, load each brick once and share one pool.
    pub fn set_streamed_volume(
        &mut self,
        device: &wgpu::Device,
        volume: &StreamedVolume,
    ) -> Result<(), RenderError> {
        let layout = volume.layout();
        for r in layout.channel_ranges() {
            check_value_range(*r)?;
        }
        let desc = layout.volume;
        check_value_range(desc.value_range)?;
        self.drop_volume();
        let b = OutOfCore::new(
            device,
            volume.clone(),
            self.options.mip_skipping,
            self.options.dvr_skipping,
        )?;
        self.backend = Some(Backend::OutOfCore(Box::new(b)));
        self.volume_dims = Some(desc.dims);
        self.value_range = desc.value_range;
        Ok(())
    }

    /// The streamed volume drawn, `None` in core or without a volume: its
    /// configuration ([`StreamedVolume::configure`]), failures and retries.
    pub fn streamed_volume(&self) -> Option<&StreamedVolume> {
        self.backend
            .as_ref()
            .and_then(Backend::out_of_core)
            .map(OutOfCore::volume)
    }

    fn drop_volume(&mut self) {
        self.backend = None;
        self.volume_dims = None;
        self.prepared = None;
        self.volume_epoch += 1;
        self.frame.drop_history();
    }

    /// Sets the transfer function (and its opacity prefix-sum table), written to
    /// the GPU only when it changed. Returns the bytes written.
    pub fn set_transfer_function(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        tf: &TransferFunction,
    ) -> Result<u64, RenderError> {
        self.tf.set(device, queue, tf)
    }

    /// Draws a label map over the image in the same ray, or removes it
    /// (`None`): its labels colour or mask the image's DVR samples, and in
    /// colour mode tint iso surfaces and MIP maxima; a slice view's pixels
    /// take the label under their slab's front sample
    /// ([`brickray_core::overlay`]). The
    /// two volumes may have different grids and placements
    /// ([`LabelOverlay::image_to_labels`],
    /// [`overlay_transform`](brickray_core::overlay_transform)); the image may
    /// be in core or out of core, and the label map is uploaded whole into
    /// one texture (it must fit the device's 3D texture limit). Fails with
    /// [`RenderError::Overlay`] when it cannot be drawn over the volume set
    /// (checked again when either changes: an overlay over a label map is
    /// not drawn) and [`RenderError::VolumeTooLarge`] past the 3D texture
    /// limit.
    pub fn set_overlay(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        overlay: Option<&LabelOverlay<'_>>,
    ) -> Result<(), RenderError> {
        if let Some(o) = overlay {
            let image_is_labels = self.backend.as_ref().is_some_and(|b| b.get().labels());
            o.validate(image_is_labels)?;
            let dims = o.labels.dims();
            let limit = device.limits().max_texture_dimension_3d;
            if dims.iter().any(|&d| d > limit) {
                return Err(RenderError::VolumeTooLarge { dims, limit });
            }
        }
        self.overlay.set(device, queue, overlay)
    }

    /// Rewrites the overlay's label table (colours, visibility, selection,
    /// hover) without uploading its labels again. Returns the bytes written
    /// (0 without an overlay).
    pub fn set_overlay_table(&mut self, queue: &wgpu::Queue, table: &LabelTable) -> u64 {
        self.overlay.set_table(queue, table)
    }

    /// Changes what the overlay does ([`OverlayStyle`]); nothing without an
    /// overlay.
    pub fn set_overlay_style(
        &mut self,
        queue: &wgpu::Queue,
        style: OverlayStyle,
    ) -> Result<(), RenderError> {
        style.validate()?;
        self.overlay.set_style(queue, style);
        Ok(())
    }

    /// The style of the overlay drawn, `None` without one.
    pub fn overlay_style(&self) -> Option<OverlayStyle> {
        self.overlay.style()
    }

    /// Bytes of the overlay's label map on the GPU (0 without one).
    pub fn overlay_bytes(&self) -> u64 {
        self.overlay.bytes()
    }

    /// Turns the isosurface prediction buffer (Braley et al.; see
    /// `docs/prediction.md`) on with `settings`, or off with `None`. It applies
    /// to iso frames of both paths; the history is per viewport and is
    /// cleared whenever the viewport's size, the isovalue, the volume, its frame,
    /// the camera's projection, the step, the host depth's presence or these
    /// settings change.
    pub fn set_prediction(&mut self, settings: Option<Prediction>) -> Result<(), PredictionError> {
        if let Some(p) = &settings {
            p.validate()?;
        }
        self.prediction = settings;
        Ok(())
    }

    /// Makes this renderer draw a slice view of its volume (`None`: the 3D
    /// view again): a plane or a thick slab (maximum or mean), sampled at the
    /// frame's viewport resolution from the same data as the 3D view (out of
    /// core: the bricks of the one cut the views of a [`StreamedVolume`]
    /// share, refined for the slice's pixel size) and mapped through the
    /// intensity window ([`Self::set_intensity`]; grey over the volume's
    /// value range without one). The frame's camera, mode and shading are
    /// not used: the slice's orthographic camera (its frustum is the slab) is
    /// ([`SliceGeometry::camera`]). A bad plane is a typed error of
    /// `prepare` ([`PrepareError::Slice`]).
    pub fn set_slice(&mut self, slice: Option<SliceView>) {
        self.slice = slice;
    }

    /// The slice view drawn, `None` for the 3D view.
    pub fn slice(&self) -> Option<SliceView> {
        self.slice
    }

    /// Sets the intensity window and colour map of MIP frames (`None`: MIP
    /// maps through the transfer function, opaque mapping off) and slice
    /// views. The window is in the volume's raw values and maps through its
    /// value range ([`Window::normalized`]); MIP through a window is opaque
    /// where a ray met the volume.
    pub fn set_intensity(&mut self, intensity: Option<Intensity>) {
        self.intensity = intensity;
    }

    /// The intensity window in use.
    pub fn intensity(&self) -> Option<Intensity> {
        self.intensity
    }

    /// Makes every later ray-cast pass this renderer records write its GPU
    /// timestamps into a query set the host owns (`None`: no timestamps, the
    /// default): the pass's `timestamp_writes` name `writes.query_set` at
    /// `writes.beginning` and `writes.end`. The renderer never resolves or
    /// reads the query set: the host resolves it into its buffer after
    /// `prepare` (`CommandEncoder::resolve_query_set`), reads it once the
    /// submission completed and converts ticks with
    /// `Queue::get_timestamp_period` (nanoseconds a tick). The timestamps
    /// bracket the ray-cast pass only ([`PassTimestamps`]).
    ///
    /// Checked before anything changes: without
    /// [`wgpu::Features::TIMESTAMP_QUERY`] on `device` (the renderer's device,
    /// on which the query set was created) it fails with
    /// [`RenderError::MissingFeature`]; a query set not of type timestamp, an
    /// index not below its count, or equal indices fail with
    /// [`RenderError::BadTimestampQuery`]. The timestamps stay set until
    /// replaced.
    pub fn set_pass_timestamps(
        &mut self,
        device: &wgpu::Device,
        writes: Option<PassTimestamps>,
    ) -> Result<(), RenderError> {
        if let Some(w) = &writes {
            w.check(device)?;
        }
        self.pass_timestamps = writes;
        Ok(())
    }

    /// Where the ray-cast pass writes its timestamps, `None` when it does not.
    pub fn pass_timestamps(&self) -> Option<&PassTimestamps> {
        self.pass_timestamps.as_ref()
    }

    /// The prediction settings in use.
    pub fn prediction(&self) -> Option<Prediction> {
        self.prediction
    }

    /// Diagnostics for benchmarks, tests and the prediction-buffer image: the
    /// buffer holding the last predicted frame's per-pixel [`TraversalClass`]
    /// codes (u32, row-major over the viewport; `COPY_SRC`), with the byte
    /// offset and size of that range. `None` when the last frame did not predict.
    pub fn prediction_classes(&self) -> Option<(&wgpu::Buffer, u64, u64)> {
        let h = self.frame.history()?;
        let (offset, size) = h.classes();
        Some((&h.buffer, offset, size))
    }

    /// Statistics of the last frame (out of core: this view's).
    pub fn stats(&self) -> RendererStats {
        RendererStats {
            frame: self.last_frame,
            out_of_core: self
                .backend
                .as_ref()
                .and_then(Backend::out_of_core)
                .map(OutOfCore::stats),
        }
    }

    /// True when another frame of the same view would change the image (out of
    /// core: bricks still arriving or being refined). A viewer redraws while this
    /// holds and may sleep when it does not.
    pub fn wants_redraw(&self) -> bool {
        self.backend
            .as_ref()
            .is_some_and(|b| b.get().wants_redraw())
    }

    /// Out of core, diagnostics: the latest usage counts read back for this
    /// view (rays that reached each data leaf of that frame's cut), whatever
    /// the policy; `None` in core or before the first read-back.
    pub fn last_usage(&self) -> Option<&UsageFrame> {
        self.backend
            .as_ref()
            .and_then(Backend::out_of_core)
            .and_then(OutOfCore::last_usage)
    }

    /// The GPU texture format chosen for the volume, if one is set.
    pub fn volume_format(&self) -> Option<wgpu::TextureFormat> {
        self.backend.as_ref().map(|b| b.get().texel_format())
    }

    /// Bytes of volume data resident on the GPU (in core the texture and,
    /// once a shaded DVR frame made them, its gradients; out of core the
    /// atlas).
    pub fn volume_bytes(&self) -> u64 {
        self.backend
            .as_ref()
            .map_or(0, |b| b.get().resident_bytes())
    }

    /// Compiles the ray-cast pipelines of `settings` for the current volume now
    /// (set-up time) instead of on first use in `prepare`, so switching mode,
    /// accelerations or shading later does not stall a frame. With each
    /// setting, the pipelines its frames may switch to by themselves: without
    /// empty-space skipping where the volume's rule may turn it off (a new
    /// transfer function in core, a new cut out of core), and out of core
    /// with and without fading leaves (a cut's fades start and end as bricks
    /// arrive): up to four per setting.
    pub fn warm_up(
        &mut self,
        device: &wgpu::Device,
        settings: &[brickray_core::RenderSettings],
    ) -> Result<(), RenderError> {
        let Some(b) = self.backend.as_ref() else {
            return Ok(());
        };
        let backend = b.get();
        let layouts = [
            self.frame.layout(),
            self.tf.layout(),
            backend.layout(),
            self.overlay.layout(),
        ];
        for s in settings {
            let v = prepare::frame_variant(b, s, false, self.prediction, self.overlay.style());
            for w in v.siblings(backend.kind(), s.accel.empty_space_skipping) {
                self.kernels.pipeline(device, backend.kind(), layouts, w)?;
            }
        }
        Ok(())
    }

    /// Diagnostics for tests and benchmarks: the ray-cast and slice
    /// pipelines compiled so far (each on first use, or by
    /// [`warm_up`](Self::warm_up)).
    pub fn compiled_pipelines(&self) -> usize {
        self.kernels.compiled()
    }

    /// Asks what lies under `pixels` (viewport coordinates): the next
    /// [`prepare`](Self::prepare) copies their depth after its pass, and
    /// [`take_picks`](Self::take_picks) returns them a frame or two later,
    /// once the host's GPU has run that frame (never waited for). At most
    /// [`MAX_PICKS`] pixels may be queued ([`PrepareError::TooManyPicks`]);
    /// pixels outside the next frame's viewport are dropped.
    pub fn request_picks(&mut self, pixels: &[[u32; 2]]) -> Result<(), PrepareError> {
        self.picker.request(pixels)
    }

    /// The picks read back since the last call ([`Pick`]: the depth written
    /// under the pixel and the point there, in volume texture coordinates
    /// and world space, unprojected with the camera of the frame that drew
    /// it). A label map's id there is
    /// `brickray_core::labels::label_at(volume, point.texture)`.
    pub fn take_picks(&mut self) -> Vec<Pick> {
        self.picker.take()
    }

    /// Diagnostics for benchmarks and tests: an `R32Uint` texture (the viewport's
    /// size, `COPY_SRC`) holding the volume samples each ray took in the last
    /// prepared frame (march and iso refinement; gradient taps excluded).
    pub fn sample_count_texture(&self) -> Option<&wgpu::Texture> {
        self.frame.outputs().map(|o| &o.samples)
    }

    /// Records the composite draw into the host's pass: sets the pass's viewport
    /// to the frame's, blends premultiplied over the host's colour and, when the
    /// pass has a depth attachment, writes the volume's depth (the host's depth
    /// where the volume put none).
    pub fn render(&self, pass: &mut wgpu::RenderPass<'_>) -> Result<(), RenderError> {
        let p = self.prepared.ok_or(RenderError::NotPrepared)?;
        self.compositor.draw(pass, p.viewport, p.convention)
    }
}

/// Refuses a value range that is not finite or whose width is not (every
/// sample would normalize to NaN or to one value).
fn check_value_range(range: [f32; 2]) -> Result<(), RenderError> {
    let [lo, hi] = range;
    if lo.is_finite() && hi.is_finite() && (hi - lo).is_finite() {
        Ok(())
    } else {
        Err(RenderError::BadValueRange(range))
    }
}
