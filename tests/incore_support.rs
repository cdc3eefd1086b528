//! What the in-core GPU test files share (`gpu_incore.rs`, images against
//! the reference; `gpu_incore_rays.rs`, what a ray's march decides): a
//! scene drawn in core on the GPU and by the CPU reference.

use brickray::{
    Camera, FrameDesc, RenderMode, RenderSettings, TransferFunction, Volume, VolumeFrame,
    VolumeRenderer,
};
use brickray_harness::Offscreen;
use brickray_reference::{ReferenceOptions, assert_close, render_reference};

use brickray_harness::{shared_gpu as gpu, target_desc as targets};

pub(crate) struct Scene<'a> {
    pub(crate) vol: &'a Volume,
    pub(crate) tf: &'a TransferFunction,
    pub(crate) frame: VolumeFrame,
    pub(crate) camera: Camera,
    pub(crate) settings: RenderSettings,
    pub(crate) size: u32,
}

impl Scene<'_> {
    pub(crate) fn new<'a>(
        vol: &'a Volume,
        tf: &'a TransferFunction,
        mode: RenderMode,
        size: u32,
    ) -> Scene<'a> {
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        Scene {
            vol,
            tf,
            frame,
            camera: Camera::orbit(frame.center(), 2.0, 0.5, 0.3),
            settings: RenderSettings {
                mode,
                ..Default::default()
            },
            size,
        }
    }

    /// Renders on the GPU into a fresh target; returns RGBA8 and depth.
    pub(crate) fn gpu(&self) -> (Vec<u8>, Vec<f32>) {
        let (rgba, depth, _) = self.gpu_counted();
        (rgba, depth)
    }

    /// [`Scene::gpu`], and the mean volume samples per ray over rays that
    /// took any.
    pub(crate) fn gpu_counted(&self) -> (Vec<u8>, Vec<f32>, f64) {
        let g = gpu();
        // MIP and DVR skip whenever the settings ask, so that the
        // accelerations' test exercises skipping on every volume and TF (by
        // default the head CT's macro cells turn MIP's off, and a TF that
        // leaves few cells transparent DVR's;
        // mip_skips_where_the_macro_cells_say_it_pays,
        // dvr_skips_where_enough_cells_are_transparent).
        let options = brickray::RendererOptions {
            mip_skipping: brickray::SkipRule::Always,
            dvr_skipping: brickray::SkipRule::Always,
            ..Default::default()
        };
        let mut r = VolumeRenderer::with_options(&g.device, targets(), options).unwrap();
        r.set_volume(&g.device, &g.queue, self.vol).unwrap();
        r.set_transfer_function(&g.device, &g.queue, self.tf)
            .unwrap();
        let target = Offscreen::new(&g.device, self.size, self.size);
        let mut enc = g.device.create_command_encoder(&Default::default());
        let desc = FrameDesc {
            camera: self.camera,
            frame: self.frame,
            viewport: brickray::Viewport::full(self.size, self.size),
            settings: self.settings,
            host_depth: None,
            time: None,
        };
        r.prepare(&g.device, &g.queue, &mut enc, &desc).unwrap();
        {
            let mut pass = target.pass(&mut enc, true);
            r.render(&mut pass).unwrap();
        }
        g.submit_wait(enc);
        let counts = brickray_harness::predict::sample_counts(g, &r);
        let spr = brickray_harness::predict::samples_per_ray(&counts);
        (target.read_color(g), target.read_depth(g), spr)
    }

    pub(crate) fn reference(&self) -> Vec<u8> {
        self.reference_with(ReferenceOptions::new(self.size, self.size))
    }

    /// The CPU reference of the scene with options `o`, RGBA8 over black.
    pub(crate) fn reference_with(&self, o: ReferenceOptions) -> Vec<u8> {
        render_reference(
            self.vol,
            &self.frame,
            self.tf,
            &self.camera,
            &self.settings,
            &o,
        )
        .to_rgba8([0.0; 3])
    }

    pub(crate) fn check_reference(&self, name: &str, min_db: f64) {
        let (gpu, _) = self.gpu();
        let cpu = self.reference();
        assert!(
            gpu.chunks_exact(4)
                .any(|p| p[0] > 10 || p[1] > 10 || p[2] > 10),
            "{name}: GPU image is black"
        );
        let cmp = assert_close(name, &gpu, &cpu, self.size, self.size, min_db)
            .unwrap_or_else(|e| panic!("{e}"));
        eprintln!("{name}: {cmp}");
    }
}

pub(crate) fn head_ct() -> Option<Volume> {
    let path = brickray_harness::shared_volume("invesalius_cranium_ct")?;
    Some(brickray::io::read_volume(path).expect("head CT reads"))
}

/// Marschner-Lobb's translucent ramp, reaching `opacity` at 0.9: the
/// termination and adaptive-step tests' TF.
pub(crate) fn translucent_ramp(opacity: f32) -> TransferFunction {
    TransferFunction::from_points(
        &[(0.2, [0.3, 0.6, 1.0, 0.0]), (0.9, [1.0, 0.8, 0.5, opacity])],
        256,
    )
}
