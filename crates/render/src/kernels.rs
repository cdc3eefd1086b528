//! The ray-cast kernels: one shader module per volume backend and one compute
//! pipeline per [`Variant`] (mode, ERT, ESS, shading and the isosurface
//! prediction's switches as WGSL override constants), compiled on first use. On lavapipe a specialised out-of-core
//! pipeline runs about 1.5x faster than one that branches on the mode.

use crate::error::RenderError;
use crate::gpu;
use crate::predict::Prediction;
use crate::shaders;
use brickray_core::{OverlayMode, RenderMode, RenderSettings};
use std::collections::HashMap;

/// The workgroup size of the kernels (`@workgroup_size(8, 8, 1)`).
pub(crate) use crate::gpu::WORKGROUP;

/// The ray caster's entry point in both kernels.
pub(crate) const ENTRY_RAYCAST: &str = "main";
/// The slice view's entry point in both kernels (slice.wgsl).
pub(crate) const ENTRY_SLICE: &str = "slice_main";

/// Bind groups of a kernel: frame, transfer function, volume, overlay.
pub(crate) const BIND_GROUPS: u32 = 4;

/// The kernel's mode (`MODE_*` in modes.wgsl).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub(crate) enum KernelMode {
    Dvr = 0,
    Iso = 1,
    Mip = 2,
}

impl KernelMode {
    /// Every mode with its WGSL name, for the reflection test.
    #[cfg(test)]
    pub(crate) const ALL: [(&'static str, KernelMode); 3] = [
        ("MODE_DVR", KernelMode::Dvr),
        ("MODE_ISO", KernelMode::Iso),
        ("MODE_MIP", KernelMode::Mip),
    ];
}

/// Which volume backend a kernel serves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum KernelKind {
    InCore,
    OutOfCore,
    /// A multi-channel volume in core (`shaders/channels.wgsl`).
    Channels,
    /// A multi-channel volume out of core (`shaders/ooc_channels.wgsl`).
    OutOfCoreChannels,
}

/// The switches compiled into a pipeline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) struct Variant {
    pub(crate) mode: KernelMode,
    pub(crate) ert: bool,
    pub(crate) ess: bool,
    pub(crate) shade: bool,
    /// The prediction buffer (iso only; predict.wgsl) and its guard and
    /// sparse skipping switches.
    pub(crate) predict: bool,
    pub(crate) guard: bool,
    pub(crate) sparse_ess: bool,
    /// DVR with the pre-integrated table.
    pub(crate) preint: bool,
    /// Out of core: the visible weights of the usage feedback
    /// (`shaders/feedback.wgsl`, `LodMetric::VisibleError`).
    pub(crate) weights: bool,
    /// The slice view's entry point (slice.wgsl) instead of the ray caster.
    pub(crate) slice: bool,
    /// A label map: nearest texels loaded at integer coordinates.
    pub(crate) labels: bool,
    /// A label map with smooth boundaries (also a label map over the
    /// image).
    pub(crate) smooth_labels: bool,
    /// A label map over the image (`OVERLAY` in overlay.wgsl: 0 none, 1
    /// colour, 2 mask).
    pub(crate) overlay: u32,
    /// Channels of a multi-channel volume (`CHANNELS` in channels.wgsl; 0
    /// for the single-channel kernels, which do not declare it).
    pub(crate) channels: u32,
    /// DVR classifies each sample with its spread (`SPREAD` in modes.wgsl;
    /// out of core, a volume whose source has spreads).
    pub(crate) spread: bool,
    /// Shaded DVR reads the per-voxel gradients (`GRADIENTS` in modes.wgsl;
    /// in core, once they are made).
    pub(crate) gradients: bool,
    /// Out of core: some leaf of the cut applied last fades (`FADES` in
    /// modes.wgsl; without, a sample reads its own brick alone).
    pub(crate) fades: bool,
    /// Out of core: the index is an octree (every level splits every axis;
    /// `OCT_OCTREE` in brickray-index's traversal library, which folds the
    /// split masks away). The in-core kernels do not declare it.
    pub(crate) octree: bool,
}

/// The out-of-core kernels' override of brickray-index's traversal library:
/// the index is an octree ([`Variant::octree`]).
pub(crate) const OCTREE_OVERRIDE: &str = "OCT_OCTREE";

/// The override constants of a pipeline, by WGSL name (modes.wgsl,
/// predict.wgsl).
pub(crate) const OVERRIDES: [&str; 15] = [
    "MODE",
    "ERT",
    "ESS",
    "SHADE",
    "PREDICT",
    "GUARD",
    "SPARSE_ESS",
    "PREINT",
    "WEIGHTS",
    "LABELS",
    "SMOOTH_LABELS",
    "SPREAD",
    "GRADIENTS",
    "FADES",
    "OVERLAY",
];

impl Variant {
    /// The variant of validated settings, with `prediction`
    /// when the host enabled it (it applies to the iso mode, in both kernels)
    /// and the visible weights when the backend measures them
    /// (`VolumeBackend::measures_weights`).
    /// A label map (`labels`) is drawn without pre-integration and shaded
    /// only with smooth boundaries
    /// (the gradient of ids, and segments interpolated between ids, are not
    /// the data). A label map over an intensity image (`overlay`) applies to
    /// DVR, and in colour mode tints iso surfaces and MIP maxima.
    pub(crate) fn of(
        s: &RenderSettings,
        prediction: Option<Prediction>,
        weights: bool,
        labels: bool,
        overlay: Option<OverlayMode>,
    ) -> Variant {
        let mode = match s.mode {
            RenderMode::Iso { .. } => KernelMode::Iso,
            RenderMode::Mip => KernelMode::Mip,
            _ => KernelMode::Dvr,
        };
        let v = Variant {
            mode,
            ert: s.accel.early_termination.is_some(),
            ess: s.accel.empty_space_skipping,
            // A label map is shaded only with smooth boundaries (the normal
            // of its boundary's filtered indicator).
            shade: s.shading.enabled && (!labels || s.smooth_labels),
            predict: false,
            guard: false,
            sparse_ess: false,
            preint: s.preintegrated && mode == KernelMode::Dvr && !labels,
            weights,
            slice: false,
            labels,
            smooth_labels: s.smooth_labels && (labels || overlay.is_some()),
            // Iso and MIP are tinted in colour mode; the mask is DVR's.
            overlay: match overlay {
                Some(m) if !labels && (mode == KernelMode::Dvr || m == OverlayMode::Color) => {
                    overlay_id(m)
                }
                _ => 0,
            },
            channels: 0,
            spread: false,
            gradients: false,
            fades: false,
            octree: false,
        };
        match prediction {
            Some(p) if mode == KernelMode::Iso => Variant {
                predict: true,
                guard: p.guard,
                sparse_ess: p.sparse_ess,
                ..v
            },
            _ => v,
        }
    }

    /// The slice view's pipeline (the switches of the ray caster off; the
    /// visible weights when the backend measures them; a label map over an
    /// intensity image, nearest).
    pub(crate) fn slice(weights: bool, labels: bool, overlay: Option<OverlayMode>) -> Variant {
        Variant {
            mode: KernelMode::Mip,
            ert: false,
            ess: false,
            shade: false,
            predict: false,
            guard: false,
            sparse_ess: false,
            preint: false,
            weights,
            slice: true,
            labels,
            smooth_labels: false,
            overlay: overlay.filter(|_| !labels).map_or(0, overlay_id),
            channels: 0,
            spread: false,
            gradients: false,
            fades: false,
            octree: false,
        }
    }

    /// The multi-channel kernel's slice view for `channels` channels.
    pub(crate) fn channel_slice(channels: u32, overlay: Option<OverlayMode>) -> Variant {
        Variant {
            channels,
            ..Variant::slice(false, false, overlay)
        }
    }

    /// The multi-channel kernel's pipeline for `channels` channels: mode,
    /// early termination, skipping and shading as the settings say, a label
    /// map over the channels as for one channel; no pre-integration,
    /// prediction or labels (channels.wgsl draws none of them).
    pub(crate) fn channels(
        s: &RenderSettings,
        channels: u32,
        overlay: Option<OverlayMode>,
    ) -> Variant {
        let v = Variant::of(s, None, false, false, overlay);
        Variant {
            preint: false,
            channels,
            ..v
        }
    }

    /// True when the variant predicts (its frames use the history).
    pub(crate) fn predicts(&self) -> bool {
        self.predict
    }

    /// The variants a view drawn with this one may switch to with no change
    /// of its settings, this one first: where `skipping_asked` (the settings
    /// ask for empty-space skipping) and the view draws DVR or MIP of one
    /// channel, without skipping as well, which the backend's rule may choose (in core when the
    /// transfer function changes, out of core with each plan); out of core
    /// (`kind`), each with and without a fading leaf ([`Variant::fades`],
    /// which changes whenever bricks arrive or a fade ends).
    pub(crate) fn siblings(self, kind: KernelKind, skipping_asked: bool) -> Vec<Variant> {
        let one_channel = matches!(kind, KernelKind::InCore | KernelKind::OutOfCore);
        let mut ess = vec![self.ess];
        if one_channel && skipping_asked && self.mode != KernelMode::Iso && !self.slice {
            ess.push(!self.ess);
        }
        let mut fades = vec![self.fades];
        if matches!(kind, KernelKind::OutOfCore | KernelKind::OutOfCoreChannels) {
            fades.push(!self.fades);
        }
        let mut out = Vec::new();
        for &f in &fades {
            for &e in &ess {
                out.push(Variant {
                    ess: e,
                    fades: f,
                    ..self
                });
            }
        }
        out
    }

    /// The override constants of the pipeline for the `kind` kernel (the
    /// single-channel kernels do not declare `CHANNELS`, the in-core ones
    /// not `OCT_OCTREE`).
    fn constants(&self, kind: KernelKind) -> Vec<(&'static str, f64)> {
        let mut c = self.shared_constants().to_vec();
        if self.channels > 0 {
            c.push(("CHANNELS", self.channels as f64));
        }
        if matches!(kind, KernelKind::OutOfCore | KernelKind::OutOfCoreChannels) {
            c.push((OCTREE_OVERRIDE, if self.octree { 1.0 } else { 0.0 }));
        }
        c
    }

    fn shared_constants(&self) -> [(&'static str, f64); 15] {
        let b = |x: bool| if x { 1.0 } else { 0.0 };
        let v = [
            self.mode as u32 as f64,
            b(self.ert),
            b(self.ess),
            b(self.shade),
            b(self.predict),
            b(self.guard),
            b(self.sparse_ess),
            b(self.preint),
            b(self.weights),
            b(self.labels),
            b(self.smooth_labels),
            b(self.spread),
            b(self.gradients),
            b(self.fades),
            self.overlay as f64,
        ];
        std::array::from_fn(|i| (OVERRIDES[i], v[i]))
    }
}

/// The `OVERLAY` id of a mode (overlay.wgsl).
pub(crate) fn overlay_id(mode: OverlayMode) -> u32 {
    match mode {
        OverlayMode::Color => 1,
        OverlayMode::Mask => 2,
    }
}

/// One backend's shader module, pipeline layout and pipelines.
#[derive(Debug)]
struct Kernel {
    label: &'static str,
    module: wgpu::ShaderModule,
    layout: wgpu::PipelineLayout,
    pipelines: HashMap<Variant, wgpu::ComputePipeline>,
}

/// Owner of the ray-cast shader modules and pipelines.
#[derive(Debug, Default)]
pub(crate) struct Kernels {
    kernels: HashMap<KernelKind, Kernel>,
}

/// Whether the kernels can run on `backend`. OpenGL's shading language
/// cannot load from a depth texture, which both ray casters do to clip their
/// rays at the host's depth, so wgpu would refuse their pipelines; the check
/// says so before any GPU object is created.
pub(crate) fn check_backend(backend: wgpu::Backend) -> Result<(), RenderError> {
    match backend {
        wgpu::Backend::Gl => Err(RenderError::UnsupportedBackend {
            backend,
            reason: "GLSL cannot load from the depth texture the ray casters read \
                     (the host's depth); use Vulkan, Metal or DirectX 12",
        }),
        _ => Ok(()),
    }
}

/// Checks the device limits every kernel needs.
pub(crate) fn check_limits(device: &wgpu::Device) -> Result<(), RenderError> {
    let l = device.limits();
    gpu::need(
        "max_bind_groups",
        BIND_GROUPS as u64,
        l.max_bind_groups as u64,
    )?;
    gpu::need(
        "max_compute_invocations_per_workgroup",
        (WORKGROUP[0] * WORKGROUP[1]) as u64,
        l.max_compute_invocations_per_workgroup as u64,
    )?;
    gpu::need(
        "max_compute_workgroup_size_x",
        WORKGROUP[0] as u64,
        l.max_compute_workgroup_size_x as u64,
    )?;
    gpu::need(
        "max_compute_workgroup_size_y",
        WORKGROUP[1] as u64,
        l.max_compute_workgroup_size_y as u64,
    )?;
    Ok(())
}

impl Kernels {
    /// Pipelines compiled so far, over every kernel.
    pub(crate) fn compiled(&self) -> usize {
        self.kernels.values().map(|k| k.pipelines.len()).sum()
    }

    /// The pipeline of `variant` for the `kind` backend, whose bind group layouts
    /// are `groups` (frame, transfer function, volume, overlay); compiled on
    /// first use.
    pub(crate) fn pipeline(
        &mut self,
        device: &wgpu::Device,
        kind: KernelKind,
        groups: [&wgpu::BindGroupLayout; 4],
        variant: Variant,
    ) -> Result<&wgpu::ComputePipeline, RenderError> {
        let k = match self.kernels.entry(kind) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                e.insert(Kernel::new(device, kind, groups)?)
            }
        };
        if !k.pipelines.contains_key(&variant) {
            let constants = variant.constants(kind);
            let p = gpu::scoped(device, k.label, || {
                device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(k.label),
                    layout: Some(&k.layout),
                    module: &k.module,
                    entry_point: Some(if variant.slice {
                        ENTRY_SLICE
                    } else {
                        ENTRY_RAYCAST
                    }),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants: &constants,
                        ..Default::default()
                    },
                    cache: None,
                })
            })?;
            k.pipelines.insert(variant, p);
        }
        Ok(&k.pipelines[&variant])
    }
}

impl Kernel {
    fn new(
        device: &wgpu::Device,
        kind: KernelKind,
        groups: [&wgpu::BindGroupLayout; 4],
    ) -> Result<Kernel, RenderError> {
        let (label, source) = match kind {
            KernelKind::InCore => ("brickray-render raycast in core", shaders::incore()),
            KernelKind::OutOfCore => ("brickray-render raycast out of core", shaders::ooc()),
            KernelKind::Channels => ("brickray-render raycast channels", shaders::channels()),
            KernelKind::OutOfCoreChannels => (
                "brickray-render raycast channels out of core",
                shaders::ooc_channels(),
            ),
        };
        let module = gpu::scoped(device, label, || {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            })
        })?;
        let layout = gpu::scoped(device, label, || {
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &groups.map(Some),
                immediate_size: 0,
            })
        })?;
        Ok(Kernel {
            label,
            module,
            layout,
            pipelines: HashMap::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// OpenGL is refused with a typed error naming the backend (its GLSL
    /// cannot compile the kernels: `WGPU_BACKEND=gl` on lavapipe's machine
    /// showed every pipeline refused); every other backend passes.
    #[test]
    fn opengl_is_refused_before_any_gpu_object() {
        for b in wgpu::Backend::ALL {
            let r = check_backend(b);
            if b == wgpu::Backend::Gl {
                assert!(
                    matches!(
                        r,
                        Err(RenderError::UnsupportedBackend {
                            backend: wgpu::Backend::Gl,
                            ..
                        })
                    ),
                    "{r:?}"
                );
            } else {
                assert!(r.is_ok(), "{b:?}: {r:?}");
            }
        }
    }

    /// The variants a warm-up compiles: skipping both ways only where a
    /// backend's rule may turn it off (DVR and MIP of one channel, asked
    /// for), fades both ways only out of core; each once, the variant itself
    /// first.
    #[test]
    fn siblings_cover_what_a_backend_switches_by_itself() {
        let s = |mode| RenderSettings {
            mode,
            ..Default::default()
        };
        let iso = RenderMode::Iso {
            value: 0.5,
            color: [1.0; 3],
        };
        let cases = [
            (KernelKind::InCore, RenderMode::Dvr, true, 2),
            (KernelKind::InCore, iso, false, 1),
            (KernelKind::InCore, RenderMode::Dvr, false, 1),
            (KernelKind::OutOfCore, RenderMode::Mip, true, 4),
            (KernelKind::OutOfCore, iso, false, 2),
            (KernelKind::Channels, RenderMode::Dvr, true, 1),
            (KernelKind::OutOfCoreChannels, RenderMode::Dvr, true, 2),
        ];
        for (kind, mode, asked, n) in cases {
            let v = Variant::of(&s(mode), None, false, false, None);
            let all = v.siblings(kind, asked);
            assert_eq!(all.len(), n, "{kind:?} {mode:?} asked {asked}");
            assert_eq!(all[0], v);
            let distinct: std::collections::HashSet<_> = all.iter().collect();
            assert_eq!(distinct.len(), n, "{kind:?} {mode:?}: repeated");
            for w in &all {
                assert_eq!(
                    Variant {
                        ess: v.ess,
                        fades: v.fades,
                        ..*w
                    },
                    v
                );
            }
        }
        // A slice view samples without skipping: fades only.
        let slice = Variant::slice(false, false, None);
        assert_eq!(slice.siblings(KernelKind::OutOfCore, true).len(), 2);
    }
}
