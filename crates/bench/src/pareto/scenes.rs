//! The Pareto suite's scenes: five volumes (three shared, two procedural), each
//! with its transfer function and the modes charted.

use brickray_core::{Camera, RenderMode, TransferFunction, Volume, VolumeFrame, synthetic};
use brickray_harness::ct;

/// One volume and the modes charted on it.
pub(crate) struct Scene {
    /// Short name (file names, JSON keys).
    pub(crate) name: &'static str,
    pub(crate) volume: Volume,
    pub(crate) frame: VolumeFrame,
    pub(crate) camera: Camera,
    /// Whether its store is built as an anisotropic pyramid.
    pub(crate) anisotropic: bool,
    /// `(mode name, mode, TF)`.
    pub(crate) modes: Vec<(&'static str, RenderMode, TransferFunction)>,
}

impl Scene {
    /// Builds the scene's brick store at `path` (bricks of `brick` voxels; an
    /// anisotropic pyramid where the scene asks for one).
    pub(crate) fn build_store(&self, brick: u32, path: &std::path::Path) -> Result<(), String> {
        self.build_store_with(brick, path, false)
    }

    /// [`build_store`](Self::build_store), with each coarse voxel's spread
    /// where `spread` (`BuildOptions::spread`).
    pub(crate) fn build_store_with(
        &self,
        brick: u32,
        path: &std::path::Path,
        spread: bool,
    ) -> Result<(), String> {
        let mut reader = brickray_io::MemoryReader::new(self.volume.clone(), "memory");
        let build = brickray_store::BuildOptions {
            anisotropic: self.anisotropic,
            brick,
            spread,
            ..Default::default()
        };
        brickray_store::build(&mut reader, path, &build).map_err(|e| e.to_string())?;
        Ok(())
    }
}

/// The volumes, by name, of `wanted` (all when empty): `ct`, `ct5` (the head
/// CT with every third slice, 4.5 mm, stored as an anisotropic pyramid), `mri`,
/// `nuclei`, `ml` (Marschner-Lobb, high frequency), `noise` (procedural
/// fractal noise).
pub(crate) fn scenes(wanted: &[String], ml_side: u32) -> Result<Vec<Scene>, String> {
    let want = |n: &str| wanted.is_empty() || wanted.iter().any(|w| w == n);
    let mut out = Vec::new();
    let shared = |name: &str| -> Result<Volume, String> {
        let path = brickray_harness::shared_volume(name)
            .ok_or_else(|| format!("the pareto suite needs ../shared/data/{name}"))?;
        brickray_io::read_volume(&path).map_err(|e| e.to_string())
    };
    if want("ct") {
        let [translucent, _, iso, mip] = ct::scenes();
        out.push(scene(
            "ct",
            shared("invesalius_cranium_ct")?,
            vec![
                ("dvr", translucent.1, translucent.2),
                (iso.0, iso.1, iso.2),
                (mip.0, mip.1, mip.2),
            ],
        ));
    }
    if want("ct5") {
        let [translucent, ..] = ct::scenes();
        let mut s = scene(
            "ct5",
            ct_every_third_slice()?,
            vec![("dvr", translucent.1, translucent.2)],
        );
        s.anisotropic = true;
        out.push(s);
    }
    if want("mri") {
        let tf = brickray_harness::scenes::mri_tf();
        out.push(scene(
            "mri",
            shared("pycortex_s1_t1_mri")?,
            vec![
                ("dvr", RenderMode::Dvr, tf),
                (
                    "mip",
                    RenderMode::Mip,
                    TransferFunction::ramp(0.0, 1.0, 1.0),
                ),
            ],
        ));
    }
    if want("nuclei") {
        let tf = TransferFunction::from_points(
            &[
                (0.15, [0.0, 0.35, 0.1, 0.0]),
                (0.5, [0.3, 0.8, 0.3, 0.2]),
                (1.0, [0.6, 1.0, 0.5, 0.8]),
            ],
            512,
        );
        out.push(scene(
            "nuclei",
            shared("cells3d_nuclei_fluo")?,
            vec![
                ("dvr", RenderMode::Dvr, tf),
                (
                    "mip",
                    RenderMode::Mip,
                    TransferFunction::ramp(0.0, 1.0, 1.0),
                ),
            ],
        ));
    }
    if want("ml") {
        let tf = brickray_harness::scenes::marschner_lobb_tf();
        out.push(scene(
            "ml",
            synthetic::marschner_lobb(ml_side),
            vec![
                ("dvr", RenderMode::Dvr, tf),
                (
                    "iso",
                    RenderMode::Iso {
                        value: 0.5,
                        color: [0.9, 0.85, 0.75],
                    },
                    TransferFunction::ramp(0.0, 1.0, 1.0),
                ),
            ],
        ));
    }
    if want("noise") {
        let tf = brickray_harness::scenes::noise_tf();
        out.push(scene(
            "noise",
            brickray_harness::scenes::pareto_noise(ml_side),
            vec![("dvr", RenderMode::Dvr, tf)],
        ));
    }
    if out.is_empty() {
        return Err(format!(
            "no scene among {wanted:?} (ct, ct5, mri, nuclei, ml, noise)"
        ));
    }
    Ok(out)
}

fn scene(
    name: &'static str,
    volume: Volume,
    modes: Vec<(&'static str, RenderMode, TransferFunction)>,
) -> Scene {
    let d = volume.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    Scene {
        name,
        volume,
        frame,
        camera,
        anisotropic: false,
        modes,
    }
}

/// The shared head CT with every third slice kept (0.96 x 0.96 x 4.5 mm).
pub(crate) fn ct_every_third_slice() -> Result<Volume, String> {
    let path = brickray_harness::shared_volume("invesalius_cranium_ct")
        .ok_or("this suite needs ../shared/data/invesalius_cranium_ct")?;
    let full = brickray_io::read_volume(&path).map_err(|e| e.to_string())?;
    ct::every_third_slice(&full).ok_or_else(|| "the head CT is not i16".to_string())
}
