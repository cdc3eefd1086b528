//! GPU test of a streamed format: an OME-Zarr image served directly as a
//! `BrickSource` (no store built) renders the same image as a brick store built
//! from the raw volume it holds (PSNR >= 50 dB at the finest level; the
//! finest bricks are byte-identical, so any difference is the renderer's).

use brickray::io::ReadOptions;
use brickray::io::zarr::ZarrBrickSource;
use brickray::{
    BrickSource, Camera, FrameDesc, OutOfCoreConfig, RenderMode, RenderSettings, TransferFunction,
    VolumeFrame, VolumeRenderer,
};
use brickray_harness::{Offscreen, shared_gpu as gpu, target_desc as targets};
use brickray_reference::assert_close;
use std::sync::Arc;

fn frame(
    r: &mut VolumeRenderer,
    camera: Camera,
    wf: VolumeFrame,
    s: RenderSettings,
    size: u32,
) -> Vec<u8> {
    let g = gpu();
    let target = Offscreen::new(&g.device, size, size);
    let mut enc = g.device.create_command_encoder(&Default::default());
    let desc = FrameDesc {
        camera,
        frame: wf,
        viewport: brickray::Viewport::full(size, size),
        settings: s,
        host_depth: None,
        time: None,
    };
    r.prepare(&g.device, &g.queue, &mut enc, &desc)
        .expect("prepare");
    {
        let mut pass = target.pass(&mut enc, true);
        r.render(&mut pass).unwrap();
    }
    g.submit_wait(enc);
    target.read_color(g)
}

/// Frames until the out-of-core path converges (bounded: 600 frames; a
/// streamed OME-Zarr brick decodes up to eight chunks, slow on a loaded machine).
fn converge(
    r: &mut VolumeRenderer,
    camera: Camera,
    wf: VolumeFrame,
    s: RenderSettings,
    size: u32,
) -> Vec<u8> {
    for _ in 0..600 {
        let img = frame(r, camera, wf, s, size);
        if r.stats().out_of_core.is_some_and(|st| st.converged) {
            return img;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    panic!("not converged: {:?}", r.stats().out_of_core);
}

#[test]
fn streamed_ome_zarr_renders_as_the_built_store() {
    let Some(data) = brickray_harness::shared_data_dir() else {
        return;
    };
    for (zarr, raw) in [
        ("cryoet_tomo_v04.ome.zarr", "cryoet_tomo"),
        ("pycortex_s1_t1_v05.ome.zarr", "pycortex_s1_t1_mri"),
    ] {
        let vol = brickray::io::read_volume(brickray_harness::shared_volume(raw).unwrap()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let store = brickray_harness::store_of(&vol, &dir.path().join("v.brs"));
        let lay = store.layout().clone();
        let streamed: Arc<dyn BrickSource> = Arc::new(
            ZarrBrickSource::open(
                &data.join("formats/ome-zarr").join(zarr),
                &ReadOptions::default(),
                lay.brick,
                lay.apron,
                None,
            )
            .unwrap(),
        );
        assert_eq!(streamed.layout(), &lay, "{zarr}");
        let d = vol.desc();
        let wf = VolumeFrame::centered(d.dims, d.spacing);
        let cfg = OutOfCoreConfig {
            tolerance_px: 0.0,
            upload_budget_bytes: 1 << 30,
            ..Default::default()
        };
        let g = gpu();
        let mut a = VolumeRenderer::new(&g.device, targets()).unwrap();
        a.set_volume_source(&g.device, &g.queue, store, cfg)
            .unwrap();
        let mut b = VolumeRenderer::new(&g.device, targets()).unwrap();
        b.set_volume_source(&g.device, &g.queue, streamed, cfg)
            .unwrap();
        let tf = TransferFunction::from_points(
            &[
                (0.3, [0.9, 0.7, 0.5, 0.0]),
                (0.6, [1.0, 0.9, 0.8, 0.08]),
                (1.0, [1.0, 1.0, 1.0, 0.4]),
            ],
            256,
        );
        for (name, mode) in [("dvr", RenderMode::Dvr), ("mip", RenderMode::Mip)] {
            a.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
            b.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
            let s = RenderSettings {
                mode,
                ..Default::default()
            };
            let cam = Camera::orbit(wf.center(), 2.0, 0.5, 0.3);
            let built = converge(&mut a, cam, wf, s, 128);
            let direct = converge(&mut b, cam, wf, s, 128);
            let nonblack = built
                .chunks(4)
                .filter(|p| p[..3].iter().any(|&c| c > 8))
                .count();
            assert!(
                nonblack > 128 * 128 / 20,
                "{zarr} {name}: the reference image is nearly empty"
            );
            let cmp = assert_close(
                &format!("zarr_{raw}_{name}"),
                &direct,
                &built,
                128,
                128,
                50.0,
            )
            .unwrap_or_else(|e| panic!("{zarr} {name}: {e}"));
            eprintln!("{zarr} {name}: {cmp}");
        }
    }
}
