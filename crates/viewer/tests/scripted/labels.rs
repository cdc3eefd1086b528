//! The viewer's label maps: drawn through their colour table, a click that
//! selects, and label maps over the image they segment (a file, an OME-Zarr
//! label image, a label store), each screenshot against the library.

use super::*;

/// A label map: the shared Brodmann atlas opened from its sidecar (a label
/// map by its `labels` list), its mricron colour table loaded and three areas
/// shown; the screenshot against the library drawing the same table.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn label_map_with_its_colour_table_matches_the_library() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let Some(data) = brickray_harness::shared_data_dir() else {
        return;
    };
    let atlas = data.join("labels/mricron_brodmann_labels/mricron_brodmann_labels.json");
    let lut = data.join("formats/nifti/mricron_brodmann.nii.lut");
    let png = dir.path().join("labels.png");
    let script = format!(
        "open {atlas}\nbackground 0 0 0\noverlays off\nlabels table {lut}\n\
         labels show-only 4 6 17 22\ncamera orbit 30 15 1.0\nwait converged\n\
         screenshot {png}\nquit\n",
        atlas = atlas.display(),
        lut = lut.display(),
        png = png.display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(120));
    let volume = brickray::io::read_volume(&atlas).expect("the atlas");
    assert!(volume.desc().kind.is_labels());
    let mut table =
        brickray::LabelTable::from_file_bytes(&std::fs::read(&lut).expect("the .lut")).unwrap();
    table.show_only(&[4, 6, 17, 22]);
    let (shot, w, h) = read_png(&png);
    let (camera, _, _) = sidecar(&png);
    let mut lib = LabelLibrary::new(&volume, camera, w, h);
    let lib = lib.draw(&table);
    let lit = lit_pixels(&shot);
    assert!(lit * 50 > (w * h) as usize, "only {lit} lit pixels");
    let cmp = brickray_reference::assert_close("viewer-labels", &shot, &lib, w, h, MIN_PSNR_DB)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("viewer label map: {cmp}");
}

/// A click selects: the Brodmann atlas seen from close by, a scripted click
/// (`pick`) at view pixel (100, 100) selects the label there (the others
/// fade to 0), and the screenshot equals the library's image with the label
/// the library's own pick finds at that pixel selected.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn a_click_selects_the_label_under_it() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let Some(data) = brickray_harness::shared_data_dir() else {
        return;
    };
    let atlas = data.join("labels/mricron_brodmann_labels/mricron_brodmann_labels.json");
    let png = dir.path().join("picked.png");
    let script = format!(
        "open {atlas}\nbackground 0 0 0\noverlays off\ncamera orbit 30 15 0.5\nwait converged\n\
         pick 100 100\nwait 4\nscreenshot {png}\nquit\n",
        atlas = atlas.display(),
        png = png.display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(120));
    let volume = brickray::io::read_volume(&atlas).expect("the atlas");
    let (shot, w, h) = read_png(&png);
    let (camera, _, _) = sidecar(&png);
    let mut lib = LabelLibrary::new(&volume, camera, w, h);
    let mut table = brickray::LabelTable::default();
    lib.renderer.request_picks(&[[100, 100]]).expect("pick");
    let mut picks = Vec::new();
    for _ in 0..4 {
        lib.draw(&table);
        picks.extend(lib.renderer.take_picks());
    }
    let point = picks
        .first()
        .and_then(|p| p.point)
        .expect("the pixel shows the atlas");
    let id = brickray::core::labels::label_at(&volume, point.texture);
    assert_ne!(id, 0, "a label, not the background");
    table.selected.insert(id);
    let lib = lib.draw(&table);
    let lit = lit_pixels(&shot);
    assert!(
        lit > 50,
        "only {lit} lit pixels: the selected label is drawn"
    );
    let cmp = brickray_reference::assert_close("viewer-picked", &shot, &lib, w, h, MIN_PSNR_DB)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("viewer click on label {id}: {cmp}");
}

/// The library drawing a label map in core, as the viewer's screenshots are
/// compared with.
struct LabelLibrary {
    renderer: VolumeRenderer,
    target: brickray_harness::Offscreen,
    desc: FrameDesc<'static>,
}

impl LabelLibrary {
    fn new(volume: &brickray::Volume, camera: Camera, w: u32, h: u32) -> LabelLibrary {
        let gpu = brickray_harness::shared_gpu();
        let mut renderer =
            VolumeRenderer::new(&gpu.device, brickray_harness::target_desc()).expect("renderer");
        renderer
            .set_volume(&gpu.device, &gpu.queue, volume)
            .expect("volume");
        let d = volume.desc();
        LabelLibrary {
            renderer,
            target: brickray_harness::Offscreen::new(&gpu.device, w, h),
            desc: FrameDesc::new(camera, VolumeFrame::centered(d.dims, d.spacing), w, h),
        }
    }

    /// One frame through `table` over black, read back.
    fn draw(&mut self, table: &brickray::LabelTable) -> Vec<u8> {
        let gpu = brickray_harness::shared_gpu();
        self.renderer
            .set_transfer_function(&gpu.device, &gpu.queue, &table.to_transfer_function())
            .expect("table");
        brickray_harness::draw_frame(
            gpu,
            &mut self.renderer,
            &self.target,
            &self.desc,
            Some(wgpu::Color::BLACK),
        )
        .expect("draw");
        self.target.read_color(gpu)
    }
}

/// A label map over its image: the Colin27 MRI with the Brodmann atlas drawn
/// over it (`overlay`), four areas shown through the atlas's colour table and
/// the image drawn inside them only (mask: the scalp would hide the cortex);
/// the screenshot against the library drawing the same overlay.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn a_label_map_over_its_image_matches_the_library() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let Some(data) = brickray_harness::shared_data_dir() else {
        return;
    };
    let mri = data.join("mricron_ch2_mri/mricron_ch2_mri.json");
    let atlas = data.join("labels/mricron_brodmann_labels/mricron_brodmann_labels.json");
    let lut = data.join("formats/nifti/mricron_brodmann.nii.lut");
    let png = dir.path().join("overlay.png");
    let script = format!(
        "open {mri}\nbackground 0 0 0\noverlays off\ntf mri\noverlay {atlas}\n\
         labels table {lut}\nlabels show-only 4 6 17 22\noverlay mode mask\n\
         camera orbit 30 15 1.0\nwait converged\nscreenshot {png}\nquit\n",
        mri = mri.display(),
        atlas = atlas.display(),
        lut = lut.display(),
        png = png.display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(120));
    let image = brickray::io::read_volume(&mri).expect("the MRI");
    let labels = brickray::io::read_volume(&atlas).expect("the atlas");
    let mut table =
        brickray::LabelTable::from_file_bytes(&std::fs::read(&lut).expect("the .lut")).unwrap();
    table.show_only(&[4, 6, 17, 22]);
    let (shot, w, h) = read_png(&png);
    let (camera, _, _) = sidecar(&png);
    // Same grid, no placements in the sidecars: the identity.
    let style = brickray::OverlayStyle {
        mode: brickray::OverlayMode::Mask,
        opacity: 1.0,
    };
    let tf_preset = brickray::core::tf::TfPreset::Mri;
    let (lib, alone) = library_overlay(&image, &labels, &table, style, tf_preset, camera, w, h);
    let change = brickray_reference::compare(&alone, &lib, w, h);
    assert!(change.psnr_db < 30.0, "the overlay shows: {change}");
    let lit = lit_pixels(&shot);
    assert!(lit * 50 > (w * h) as usize, "only {lit} lit pixels");
    let cmp = brickray_reference::assert_close("viewer-overlay", &shot, &lib, w, h, MIN_PSNR_DB)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("viewer overlay: {cmp}; image alone vs overlay: {change}");
}

/// An OME-Zarr image with a label image (`labels/`): the cells3d nuclei and
/// their labels written as one OME-Zarr, opened; the viewer draws the label
/// image over the image with its `image-label` colours (no `--overlay`), and
/// the screenshot equals the library's overlay.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn an_ome_zarr_opens_with_its_label_image_over_it() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let Some(data) = brickray_harness::shared_data_dir() else {
        return;
    };
    let image =
        brickray::io::read_volume(data.join("cells3d_nuclei_fluo/cells3d_nuclei_fluo.json"))
            .expect("the nuclei");
    let labels = brickray::io::read_volume(
        data.join("labels/cells3d_nuclei_labels/cells3d_nuclei_labels.json"),
    )
    .expect("their labels");
    let zarr = dir.path().join("nuclei.ome.zarr");
    brickray::io::zarr::write_ome_zarr(&zarr, &image, None).expect("write the image");
    let ids = brickray::core::labels::labels_present(&labels);
    brickray::io::zarr::add_ome_zarr_labels(
        &zarr,
        "nuclei",
        &labels,
        (&brickray::LabelTable::default(), &ids),
    )
    .expect("write the labels");
    let png = dir.path().join("zarr-labels.png");
    let script = format!(
        "open {zarr}\nbackground 0 0 0\noverlays off\ncamera orbit 30 15 1.0\nwait converged\n\
         screenshot {png}\nquit\n",
        zarr = zarr.display(),
        png = png.display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(120));
    let image = brickray::io::read_volume(&zarr).expect("the image back");
    let label_dir = zarr.join("labels/nuclei");
    let labels = brickray::io::read_volume(&label_dir).expect("the labels back");
    assert!(labels.desc().kind.is_labels());
    let table = brickray::io::zarr::OmeZarr::open(&label_dir)
        .expect("the label image")
        .label_table()
        .expect("its colours");
    let (shot, w, h) = read_png(&png);
    let (camera, _, _) = sidecar(&png);
    let grey = brickray::core::tf::TfPreset::Grey;
    let style = brickray::OverlayStyle::default();
    let (lib, alone) = library_overlay(&image, &labels, &table, style, grey, camera, w, h);
    let change = brickray_reference::compare(&alone, &lib, w, h);
    assert!(change.psnr_db < 35.0, "the labels show: {change}");
    let cmp =
        brickray_reference::assert_close("viewer-zarr-labels", &shot, &lib, w, h, MIN_PSNR_DB)
            .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("viewer OME-Zarr with labels: {cmp}; image alone vs overlay: {change}");
}

/// The library drawing `labels` over `image` (same grid: the identity) with
/// `table` and `style`, the image through `preset` over its value range, in
/// core, at `camera`, over black; and the image alone.
#[allow(clippy::too_many_arguments)]
fn library_overlay(
    image: &brickray::Volume,
    labels: &brickray::Volume,
    table: &brickray::LabelTable,
    style: brickray::OverlayStyle,
    preset: brickray::core::tf::TfPreset,
    camera: Camera,
    w: u32,
    h: u32,
) -> (Vec<u8>, Vec<u8>) {
    let gpu = brickray_harness::shared_gpu();
    let mut renderer =
        VolumeRenderer::new(&gpu.device, brickray_harness::target_desc()).expect("renderer");
    renderer
        .set_volume(&gpu.device, &gpu.queue, image)
        .expect("volume");
    let d = image.desc();
    let tf = brickray::core::tf::TfModel::preset(preset, d.value_range)
        .to_table(brickray::core::tf::TABLE_ENTRIES)
        .expect("tf");
    renderer
        .set_transfer_function(&gpu.device, &gpu.queue, &tf)
        .expect("tf");
    let overlay = brickray::LabelOverlay {
        labels,
        image_to_labels: glam::DMat4::IDENTITY,
        table,
        style,
    };
    let target = brickray_harness::Offscreen::new(&gpu.device, w, h);
    let desc = FrameDesc::new(camera, VolumeFrame::centered(d.dims, d.spacing), w, h);
    let mut draw = |o: Option<&brickray::LabelOverlay<'_>>| {
        renderer
            .set_overlay(&gpu.device, &gpu.queue, o)
            .expect("overlay");
        brickray_harness::draw_frame(gpu, &mut renderer, &target, &desc, Some(wgpu::Color::BLACK))
            .expect("draw");
        target.read_color(gpu)
    };
    let lib = draw(Some(&overlay));
    (lib, draw(None))
}

/// A label store over its image: the Brodmann atlas built into a store and
/// drawn over the Colin27 MRI (`overlay STORE.brs`, mask mode): its finest
/// level fits one texture and is read whole; the screenshot equals the
/// library's overlay of that level.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn a_label_store_over_its_image_matches_the_library() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let Some(data) = brickray_harness::shared_data_dir() else {
        return;
    };
    let mri = data.join("mricron_ch2_mri/mricron_ch2_mri.json");
    let atlas = data.join("labels/mricron_brodmann_labels/mricron_brodmann_labels.json");
    let store = dir.path().join("atlas.brs");
    let mut reader = brickray::io::open(&atlas).expect("the atlas");
    let o = brickray::store::BuildOptions {
        brick: 16,
        ..Default::default()
    };
    brickray::store::build(reader.as_mut(), &store, &o).expect("build");
    let png = dir.path().join("store-overlay.png");
    let script = format!(
        "open {mri}\nbackground 0 0 0\noverlays off\ntf mri\noverlay {store}\n\
         overlay mode mask\ncamera orbit 30 15 1.0\nwait converged\nscreenshot {png}\nquit\n",
        mri = mri.display(),
        store = store.display(),
        png = png.display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(120));
    let image = brickray::io::read_volume(&mri).expect("the MRI");
    let s = brickray::store::open(&store).expect("the store");
    let labels = brickray::core::level_volume(&s, s.layout().levels - 1).expect("its finest level");
    let (shot, w, h) = read_png(&png);
    let (camera, _, _) = sidecar(&png);
    let style = brickray::OverlayStyle {
        mode: brickray::OverlayMode::Mask,
        opacity: 1.0,
    };
    let table = brickray::LabelTable::default();
    let mri_tf = brickray::core::tf::TfPreset::Mri;
    let (lib, alone) = library_overlay(&image, &labels, &table, style, mri_tf, camera, w, h);
    let change = brickray_reference::compare(&alone, &lib, w, h);
    assert!(change.psnr_db < 30.0, "the overlay shows: {change}");
    let cmp =
        brickray_reference::assert_close("viewer-store-overlay", &shot, &lib, w, h, MIN_PSNR_DB)
            .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("viewer label store over its image: {cmp}; image alone vs overlay: {change}");
}
