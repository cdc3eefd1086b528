//! A frame's recording: every view's frame checked before any GPU work, the
//! streamed volumes the views share planned once per frame, and each
//! renderer's transfer-function tables, uniforms and ray-cast pass recorded
//! into the host's encoder (the `prepare` half of the frame protocol in the
//! crate docs).

use crate::backend::Backend;
use crate::frame::FrameUniforms;
use crate::kernels::Variant;
use crate::slice::FrameMapping;
use crate::{FrameDesc, FrameStats, PrepareError, Prepared, VolumeRenderer, frame, gpu, slice};
use brickray_cache::{Classification, StreamFrame};
use brickray_core::FrameView;

impl VolumeRenderer {
    /// Checks everything `prepare` is given before any GPU work.
    fn check_frame(&self, device: &wgpu::Device, f: &FrameDesc<'_>) -> Result<(), PrepareError> {
        let limits = device.limits();
        let vp = f.viewport;
        let limit = limits.max_texture_dimension_2d;
        let groups = limits.max_compute_workgroups_per_dimension;
        let too_big = |n: u32| n > limit || n.div_ceil(gpu::WORKGROUP[0]) > groups;
        if vp.width == 0 || vp.height == 0 || too_big(vp.width) || too_big(vp.height) {
            return Err(PrepareError::BadViewport {
                width: vp.width,
                height: vp.height,
                limit,
            });
        }
        // `render` sets the pass's viewport to it: its far edges must exist
        // and lie inside a target the device can create.
        let inside =
            |origin: u32, extent: u32| origin.checked_add(extent).is_some_and(|e| e <= limit);
        if !inside(vp.x, vp.width) || !inside(vp.y, vp.height) {
            return Err(PrepareError::ViewportOutOfRange {
                viewport: vp,
                limit,
            });
        }
        f.camera.validate()?;
        f.frame.validate()?;
        f.settings.validate()?;
        if let Some(view) = f.host_depth {
            frame::check_host_depth(view, vp)?;
        }
        Ok(())
    }

    /// Writes this frame's uniforms and uploads and records the ray-cast compute
    /// pass into `encoder`. Out of core it first plans the frame (refinement,
    /// requests to the loader, uploads within the budget, index encoding); it never
    /// waits for I/O or the GPU. The host submits the encoder, then records
    /// [`Self::render`] into a pass that loads its colour and depth.
    pub fn prepare(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        desc: &FrameDesc<'_>,
    ) -> Result<FrameStats, PrepareError> {
        let stats = Self::prepare_views(device, queue, encoder, &mut [(self, desc)])?;
        Ok(stats[0])
    }

    /// [`Self::prepare`] for several renderers in one frame (a stereo pair, a
    /// 3D view beside an orthogonal view, several viewports of a viewer). Each
    /// streamed volume they share is planned once for all the views that draw
    /// it: one cut holds each node at the finest level any of them needs, each
    /// brick is loaded once into the one pool, and what each view's rays
    /// observed feeds one visibility state. The 3D views planned together
    /// must share the render mode and the transfer function
    /// ([`PrepareError::ViewsDisagree`]); slice views ([`Self::set_slice`])
    /// join any group, which then classifies as MIP (every node with data is
    /// visible). Every frame is checked before any GPU work; the stats are in
    /// the order of `views`.
    pub fn prepare_views(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        views: &mut [(&mut VolumeRenderer, &FrameDesc<'_>)],
    ) -> Result<Vec<FrameStats>, PrepareError> {
        // Everything is checked first, so that a rejected frame touches nothing.
        let mut frames = Vec::with_capacity(views.len());
        for (r, desc) in views.iter_mut() {
            r.prepared = None;
            r.mapping = None;
            let mapping = FrameMapping::new(r.slice.as_ref(), r.intensity, r.value_range, desc)?;
            // A slice is checked as the frame it is drawn as.
            let desc = mapping.frame(desc);
            r.check_frame(device, &desc)?;
            let Some(volume) = r.volume_dims.filter(|_| r.backend.is_some()) else {
                return Err(PrepareError::NoVolume);
            };
            if desc.frame.dims != volume {
                return Err(PrepareError::FrameDoesNotFit {
                    frame: desc.frame.dims,
                    volume,
                });
            }
            let channels = r.backend.as_ref().and_then(Backend::channel_count);
            if channels.is_some() {
                if r.channel_styles.is_none() {
                    return Err(PrepareError::NoChannelStyles);
                }
            } else if r.tf.current().is_none() && r.slice.is_none() {
                return Err(PrepareError::NoTransferFunction);
            }
            r.mapping = Some(mapping);
            frames.push(desc);
        }
        // A renderer that draws only slices binds a stand-in transfer function.
        for (r, _) in views.iter_mut() {
            if r.tf.current().is_none() {
                r.tf.set(device, queue, &slice::slice_tf())?;
            }
        }
        let mut views: Vec<(&mut VolumeRenderer, &FrameDesc<'_>)> = views
            .iter_mut()
            .zip(&frames)
            .map(|((r, _), d)| (&mut **r, d))
            .collect();
        let views = views.as_mut_slice();
        let mut uploaded = vec![0u64; views.len()];
        let mut done = vec![false; views.len()];
        for i in 0..views.len() {
            if done[i] {
                continue;
            }
            let (r, desc) = &mut views[i];
            if let Some(Backend::InCore(b)) = r.backend.as_mut() {
                let tf = r.tf.current().ok_or(PrepareError::NoTransferFunction)?;
                uploaded[i] = b.update(queue, desc.settings.mode, tf, r.tf.generation());
                // Shaded DVR reads the gradients (a slice view shades nothing).
                let s = &desc.settings;
                let shaded_dvr = s.shading.enabled
                    && matches!(s.mode, brickray_core::RenderMode::Dvr)
                    && r.slice.is_none();
                b.prepare_gradients(device, queue, encoder, shaded_dvr)?;
                done[i] = true;
                continue;
            }
            if let Some(Backend::Channels(b)) = r.backend.as_mut() {
                let (styles, generation) = r
                    .channel_styles
                    .as_ref()
                    .ok_or(PrepareError::NoChannelStyles)?;
                uploaded[i] = b.update(
                    device,
                    queue,
                    desc.settings.mode,
                    styles,
                    *generation,
                    desc.settings.step_factor,
                    crate::frame::adaptive_rows(&desc.settings),
                )?;
                done[i] = true;
                continue;
            }
            let group = streamed_group(views, i, &done)?;
            plan_group(device, queue, encoder, views, &group, &mut uploaded)?;
            for j in group {
                done[j] = true;
            }
        }
        views
            .iter_mut()
            .zip(uploaded)
            .map(|((r, desc), bytes)| r.record(device, queue, encoder, desc, bytes))
            .collect()
    }

    /// Records this renderer's frame after its volume was updated: the
    /// transfer function's tables, the frame's uniforms and prediction, the
    /// composite's inputs and the ray-cast pass.
    fn record(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        desc: &FrameDesc<'_>,
        mut uploaded: u64,
    ) -> Result<FrameStats, PrepareError> {
        let backend = self.backend.as_mut().ok_or(PrepareError::NoVolume)?;
        if let (Backend::OutOfCore(o), Some((styles, generation))) =
            (&mut *backend, &self.channel_styles)
        {
            uploaded += o.update_channels(
                device,
                queue,
                styles,
                *generation,
                desc.settings.step_factor,
                crate::frame::adaptive_rows(&desc.settings),
            )?;
        }
        backend.get_mut().before_pass(encoder);
        let variant_of = |settings: &brickray_core::RenderSettings, slice: bool| {
            frame_variant(
                backend,
                settings,
                slice,
                self.prediction,
                self.overlay.style(),
            )
        };
        let backend = backend.get();
        let mapping = self.mapping.ok_or(PrepareError::NoVolume)?;
        let variant = variant_of(&desc.settings, mapping.slice.is_some());
        uploaded += self.tf.prepare(
            device,
            queue,
            desc.settings.step_factor,
            backend.step_lengths() + crate::frame::adaptive_rows(&desc.settings),
            desc.settings.preintegrated
                && !backend.labels()
                && matches!(desc.settings.mode, brickray_core::RenderMode::Dvr),
            variant.spread,
        )?;
        let mut uniforms = FrameUniforms::new(desc, backend.max_leaves());
        mapping.apply(&mut uniforms);
        let predict = self
            .prediction
            .filter(|_| variant.predicts())
            .map(|p| (p, self.volume_epoch));
        let (written, prediction) = self
            .frame
            .update(device, queue, encoder, desc, uniforms, predict)?;
        uploaded += written;
        let outputs = self.frame.outputs().ok_or(PrepareError::NoVolume)?;
        uploaded += self
            .compositor
            .update(device, queue, outputs, desc.viewport)?;
        let layouts = [
            self.frame.layout(),
            self.tf.layout(),
            backend.layout(),
            self.overlay.layout(),
        ];
        let pipeline = self
            .kernels
            .pipeline(device, backend.kind(), layouts, variant)?;
        let groups = [
            self.frame.bind_group(),
            self.tf.bind_group(),
            Some(backend.bind_group()),
            Some(self.overlay.bind_group()),
        ];
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("brickray-render raycast"),
                // The host's timestamps, checked by `set_pass_timestamps`.
                timestamp_writes: self
                    .pass_timestamps
                    .as_ref()
                    .map(crate::PassTimestamps::writes),
            });
            pass.set_pipeline(pipeline);
            for (i, g) in groups.into_iter().enumerate() {
                pass.set_bind_group(i as u32, g, &[]);
            }
            let vp = desc.viewport;
            pass.dispatch_workgroups(
                vp.width.div_ceil(gpu::WORKGROUP[0]),
                vp.height.div_ceil(gpu::WORKGROUP[1]),
                1,
            );
        }
        if let Some(b) = self.backend.as_mut() {
            b.get_mut().after_pass(queue, encoder);
        }
        if let Some(out) = self.frame.outputs() {
            let size = [desc.viewport.width, desc.viewport.height];
            self.picker.record(
                queue,
                encoder,
                &out.depth_tex,
                desc.camera,
                desc.frame,
                size,
            );
        }
        self.prepared = Some(Prepared {
            viewport: desc.viewport,
            convention: desc.camera.depth,
        });
        self.last_frame = FrameStats {
            rays: desc.viewport.width as u64 * desc.viewport.height as u64,
            uploaded_bytes: uploaded,
            prediction,
            empty_space_skipping: variant.ess,
        };
        Ok(self.last_frame)
    }
}

/// The pipeline variant that draws `settings` (with `slice`, a slice view)
/// of `backend`: the multi-channel kernel's for a channel volume, else the
/// single-channel kernels' with the renderer's prediction (iso), the
/// backend's visible weights and label map, and the overlay's mode.
pub(crate) fn frame_variant(
    backend: &Backend,
    settings: &brickray_core::RenderSettings,
    slice: bool,
    prediction: Option<crate::Prediction>,
    overlay: Option<brickray_core::OverlayStyle>,
) -> Variant {
    let overlay = overlay.map(|o| o.mode);
    if let Backend::Channels(b) = backend {
        let n = b.count() as u32;
        return if slice {
            Variant::channel_slice(n, overlay)
        } else {
            Variant::channels(settings, n, overlay)
        };
    }
    if let (Backend::OutOfCore(_), Some(n)) = (backend, backend.channel_count()) {
        let v = if slice {
            Variant::channel_slice(n as u32, overlay)
        } else {
            Variant::channels(settings, n as u32, overlay)
        };
        return Variant {
            weights: backend.get().measures_weights(),
            fades: backend.get().fades(),
            octree: backend.get().octree(),
            ..v
        };
    }
    let b = backend.get();
    if slice {
        Variant {
            fades: b.fades(),
            octree: b.octree(),
            ..Variant::slice(b.measures_weights(), b.labels(), overlay)
        }
    } else {
        let v = Variant::of(
            settings,
            prediction,
            b.measures_weights(),
            b.labels(),
            overlay,
        );
        // Coarse levels classified with their spread: point-sampled DVR
        // only (iso and MIP use the mean field, pre-integrated segments
        // ignore the spread; docs/rendering-model.md). Shaded DVR of an
        // intensity volume reads the backend's gradients where it has them;
        // MIP and DVR skip empty space only where the backend says it pays.
        let dvr = v.mode == crate::kernels::KernelMode::Dvr;
        let mip = v.mode == crate::kernels::KernelMode::Mip;
        Variant {
            spread: b.spread() && dvr && !v.preint,
            gradients: b.gradients() && dvr && v.shade && !v.labels,
            ess: v.ess
                && (!mip || b.mip_skipping(settings.step_factor))
                && (!dvr || b.dvr_skipping(settings.step_factor, v.shade)),
            fades: b.fades(),
            octree: b.octree(),
            ..v
        }
    }
}

/// The views among `views[i..]` not `done` that draw the streamed volume of
/// `views[i]`, `i` first; they must agree on the classification.
fn streamed_group(
    views: &[(&mut VolumeRenderer, &FrameDesc<'_>)],
    i: usize,
    done: &[bool],
) -> Result<Vec<usize>, PrepareError> {
    let volume = |j: usize| views[j].0.streamed_volume();
    let lead = volume(i).ok_or(PrepareError::NoVolume)?;
    let group: Vec<usize> = (i..views.len())
        .filter(|&j| !done[j] && volume(j).is_some_and(|v| v.same(lead)))
        .collect();
    // The 3D views must agree; a slice agrees with any view.
    let mut views_3d = group
        .iter()
        .copied()
        .filter(|&j| views[j].0.slice.is_none());
    if let Some(first) = views_3d.next() {
        let (f, desc) = (&views[first].0, views[first].1);
        for j in views_3d {
            let (r, d) = (&views[j].0, views[j].1);
            fn styles(r: &VolumeRenderer) -> Option<&[brickray_core::ChannelStyle]> {
                r.channel_styles.as_ref().map(|(s, _)| s.as_slice())
            }
            if d.settings.mode != desc.settings.mode
                || r.tf.current() != f.tf.current()
                || styles(r) != styles(f)
            {
                return Err(PrepareError::ViewsDisagree { first, other: j });
            }
        }
    }
    Ok(group)
}

/// Plans the streamed volume drawn by the views `group` of `views` once for
/// all of them (their feedback read back first), and hands each its part.
fn plan_group(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    encoder: &mut wgpu::CommandEncoder,
    views: &mut [(&mut VolumeRenderer, &FrameDesc<'_>)],
    group: &[usize],
    uploaded: &mut [u64],
) -> Result<(), PrepareError> {
    let lead = group[0];
    let volume = views[lead]
        .0
        .streamed_volume()
        .cloned()
        .ok_or(PrepareError::NoVolume)?;
    let mut shared = volume.lock();
    let next = shared.planner.next_frame();
    let mut frame_views = Vec::with_capacity(group.len());
    for (k, &j) in group.iter().enumerate() {
        let (r, desc) = &mut views[j];
        let vp = desc.viewport;
        frame_views.push(
            FrameView::new(desc.camera, desc.frame, [vp.width, vp.height])
                .with_clip(desc.settings.clip),
        );
        if let Some(Backend::OutOfCore(o)) = r.backend.as_mut() {
            shared.planner.add_feedback(k, o.poll(next));
        }
    }
    // The transfer function the views draw with (the lead 3D view's; they
    // agree) and its generation, for the out-of-core DVR skip rule.
    let mut tf_drawn: Option<(brickray_core::TransferFunction, u64)> = None;
    let planned = {
        // The classification is the 3D views' (they agree), MIP when a slice
        // is among the views: every node with data is visible, as a slice
        // shows every value (a superset of what DVR and iso classify as
        // visible, so the 3D views draw the same image).
        let sliced = group.iter().any(|&j| views[j].0.slice.is_some());
        let lead_3d = group
            .iter()
            .copied()
            .find(|&j| views[j].0.slice.is_none())
            .unwrap_or(lead);
        let (r, desc) = &views[lead_3d];
        let tf = r.tf.current().ok_or(PrepareError::NoTransferFunction)?;
        if r.slice.is_none() && shared.needs_dvr_rule(desc.settings.mode) {
            tf_drawn = Some((tf.clone(), r.tf.generation()));
        }
        // A multi-channel volume is classified by its channels' styles.
        let (channels, tf_generation) = match &r.channel_styles {
            Some((styles, generation)) if shared.layout.is_channel_volume() => {
                (styles.as_slice(), *generation)
            }
            _ => (&[][..], r.tf.generation()),
        };
        // Kept gradients are made only for frames that shade DVR.
        let shaded_dvr = group.iter().any(|&j| {
            let s = &views[j].1.settings;
            views[j].0.slice.is_none()
                && s.shading.enabled
                && matches!(s.mode, brickray_core::RenderMode::Dvr)
        });
        let frame = StreamFrame {
            views: &frame_views,
            classification: Classification {
                mode: if sliced {
                    brickray_core::RenderMode::Mip
                } else {
                    desc.settings.mode
                },
                tf,
                channels,
                tf_generation,
            },
            feedback: &[],
            time: desc.time,
        };
        shared.plan(device, queue, encoder, &frame, shaded_dvr)?
    };
    drop(shared);
    // Without a new plan (in the background, the worker is still planning)
    // the views draw the last one.
    let Some(planned) = planned else {
        return Ok(());
    };
    uploaded[lead] += planned.bytes;
    for (k, &j) in group.iter().enumerate() {
        let (r, desc) = &mut views[j];
        let vp = desc.viewport;
        let queries = planned.plan.queries.get(k).cloned().unwrap_or_default();
        if let Some(Backend::OutOfCore(o)) = r.backend.as_mut() {
            let tf = tf_drawn.as_ref().map(|(tf, g)| (tf, *g));
            o.apply(device, queue, &planned, &queries, [vp.width, vp.height], tf)?;
        }
    }
    Ok(())
}
