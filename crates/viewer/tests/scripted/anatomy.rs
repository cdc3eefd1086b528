//! Anatomical orientation in the viewer: the shared head CT opened from its
//! DICOM series (LPS+, axial) in the four-view layout with a CT window,
//! seen from the front; the slices radiological and the volume upright, and
//! each quadrant of the screenshot the library's own rendering of that view.

use super::*;
use brickray::core::anatomy::{Direction, Orientation, RAS_TO_WORLD};

/// A number array of the sidecar.
pub(super) fn numbers(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .expect("an array")
        .iter()
        .map(|x| x.as_f64().expect("a number"))
        .collect()
}

/// The library's in-core rendering of `volume` placed by `frame`: a slice
/// view through `window`, or (no slice) the 3D view with the bone TF.
fn library_view(
    volume: &brickray::Volume,
    frame: VolumeFrame,
    camera: Camera,
    slice: Option<brickray::SliceView>,
    window: brickray::Window,
    w: u32,
    h: u32,
) -> Vec<u8> {
    let intensity = brickray::Intensity::new(window, brickray::ColorMap::Grey);
    let desc = FrameDesc::new(camera, frame, w, h);
    library_render(volume, &desc, slice, Some(intensity))
}

/// Rows `vp[1]..vp[1]+vp[3]`, columns `vp[0]..vp[0]+vp[2]` of an RGBA image
/// `w` pixels wide.
pub(super) fn crop(img: &[u8], w: u32, vp: [u32; 4]) -> Vec<u8> {
    let mut out = Vec::with_capacity((vp[2] * vp[3] * 4) as usize);
    for y in vp[1]..vp[1] + vp[3] {
        let row = ((y * w + vp[0]) * 4) as usize;
        out.extend_from_slice(&img[row..row + (vp[2] * 4) as usize]);
    }
    out
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn the_head_ct_opens_upright_in_four_views_with_a_ct_window() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let Some(data) = brickray_harness::shared_data_dir() else {
        return;
    };
    let series = data.join("formats/dicom/cranium_ct");
    let tf = dir.path().join("bone.json");
    std::fs::write(&tf, tf_json()).expect("write the TF");
    let shot = dir.path().join("four.png");
    let script = format!(
        "open {series}\nbackground 0 0 0\ntf load {tf}\nlayout four\nwindow brain\n\
         crosshair 128 110 60\ncamera view A\noverlays off\nwait 3\nscreenshot {shot}\nquit\n",
        series = series.display(),
        tf = tf.display(),
        shot = shot.display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(180));

    // The library, independently: the series' placement and its orientation.
    let reader = brickray::io::open(&series).expect("the series");
    let placement = reader.placement().expect("DICOM places its slices");
    let o = Orientation::new(placement.voxel_to_ras().expect("patient space")).unwrap();
    assert_eq!(o.code(), "LPS");
    let volume = brickray::io::read_volume(&series).expect("the series' voxels");
    let frame = o.frame(volume.desc().dims);

    let side = sidecar_json(&shot);
    assert_eq!(side["orientation"].as_str(), Some("LPS"));
    let model = numbers(&side["frame"]["model"]);
    let want = frame.model.to_cols_array();
    for (a, b) in model.iter().zip(want) {
        assert!(
            (a - b as f64).abs() < 1e-6,
            "the viewer's frame {model:?} vs {want:?}"
        );
    }
    // Seen from the front with the head up: the camera looks toward
    // posterior, its up is superior.
    let (camera, _, _) = sidecar(&shot);
    let to_ras = |v: glam::Vec3| RAS_TO_WORLD.transpose() * v.as_dvec3().normalize();
    let forward = to_ras(camera.target - camera.eye);
    assert!(
        (forward - Direction::Posterior.ras()).length() < 0.01,
        "looks along {forward}"
    );
    assert!((to_ras(camera.up) - Direction::Superior.ras()).length() < 0.01);

    let (img, w, h) = read_png(&shot);
    let window = brickray::CtPreset::Brain.window();
    let slices = side["slices"].as_array().expect("the slices");
    assert_eq!(slices.len(), 3);
    // Radiological: the screen's right is the patient's left (+i of an LPS
    // series) in axial and coronal slices, posterior (+j) in the sagittal;
    // up is anterior (-j) in the axial, superior (+k) in the others.
    let expected = [
        ([1.0, 0.0, 0.0], [0.0, -1.0, 0.0]),
        ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
    ];
    for (i, s) in slices.iter().enumerate() {
        let v3 = |v: &serde_json::Value| <[f64; 3]>::try_from(numbers(v)).expect("three numbers");
        let view = brickray::SliceView {
            centre: v3(&s["centre"]),
            right: v3(&s["right"]),
            up: v3(&s["up"]),
            height: s["height"].as_f64().expect("height"),
            slab: None,
        };
        assert_eq!((view.right, view.up), expected[i], "slice {i}");
        let vp = <[u32; 4]>::try_from(
            numbers(&s["viewport"])
                .iter()
                .map(|&x| x as u32)
                .collect::<Vec<_>>(),
        )
        .expect("a viewport");
        let got = crop(&img, w, vp);
        assert!(
            lit_pixels(&got) * 10 > (vp[2] * vp[3]) as usize,
            "slice {i} is dark"
        );
        let lib = library_view(&volume, frame, camera, Some(view), window, vp[2], vp[3]);
        let cmp = brickray_reference::assert_close(
            &format!("anatomy-slice-{i}"),
            &got,
            &lib,
            vp[2],
            vp[3],
            MIN_PSNR_DB,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        eprintln!("oriented four views, slice {i} vs library: {cmp}");
    }
    // The 3D quadrant: the bone TF from the front, the face toward the
    // viewer.
    let vp = <[u32; 4]>::try_from(
        numbers(&side["view_3d"])
            .iter()
            .map(|&x| x as u32)
            .collect::<Vec<_>>(),
    )
    .expect("the 3D view's viewport");
    let got = crop(&img, w, vp);
    assert!(
        lit_pixels(&got) * 20 > (vp[2] * vp[3]) as usize,
        "the 3D view is dark"
    );
    let lib = library_view(&volume, frame, camera, None, window, vp[2], vp[3]);
    let cmp = brickray_reference::assert_close("anatomy-3d", &got, &lib, vp[2], vp[3], MIN_PSNR_DB)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("oriented four views, 3D view vs library: {cmp}");
    let _ = h;
}
