//! A multi-channel volume in the viewer: a 2-channel OME-Zarr (two u16
//! blobs in different places, each with its own `omero` colour and window)
//! opens in core with the file's styles, and its screenshot is the
//! library's own rendering of that view (`set_channel_volume` with
//! `read_channels(..).styles()`); `channel 1 visible off` gives the
//! library's image with channel 1 hidden; in the four-view layout each
//! slice is the library's slice of the channels. With `--in-core-max 0` the
//! same file streams (every channel, as one `ChannelSource`) and its
//! screenshot is the library's in-core image of the view.

use super::*;
use brickray::io::{ChannelInfo, ReadOptions};
use brickray::{ChannelStyle, ChannelVolume, Volume, VolumeData};

/// The grid of the test volume and its spacing.
const DIMS: [u32; 3] = [48, 40, 32];
const SPACING: [f32; 3] = [1.0, 1.0, 1.5];

/// The file's colours (neither is a default palette colour, so a viewer
/// that ignored them draws something else): orange-red and azure.
const COLORS: [[u8; 3]; 2] = [[255, 64, 0], [0, 160, 255]];

/// One u16 channel: a soft blob of `peak` at `centre` (fractions of the
/// grid) over a dark background.
fn blob(centre: [f32; 3], peak: f32) -> Volume {
    let c = glam::Vec3::from_array(centre);
    let d = glam::UVec3::from_array(DIMS).as_vec3();
    let mut v = Vec::with_capacity(DIMS.iter().product::<u32>() as usize);
    for z in 0..DIMS[2] {
        for y in 0..DIMS[1] {
            for x in 0..DIMS[0] {
                let p = (glam::Vec3::new(x as f32, y as f32, z as f32) + 0.5) / d;
                let r2 = (p - c).length_squared();
                v.push((300.0 + peak * (-r2 * 60.0).exp()) as u16);
            }
        }
    }
    Volume::with_data_range(DIMS, SPACING, VolumeData::U16(v)).expect("a channel")
}

/// Writes the 2-channel OME-Zarr: channel 0 ("nuclei") a blob at low x,
/// channel 1 ("membrane") one at high x, each with its colour and window.
fn write_two_channels(root: &Path) {
    let volume = ChannelVolume::new(vec![
        blob([0.3, 0.45, 0.5], 40000.0),
        blob([0.72, 0.55, 0.5], 52000.0),
    ])
    .expect("two channels");
    let rgb = |c: [u8; 3]| c.map(|v| f32::from(v) / 255.0);
    let info = [
        ChannelInfo {
            label: Some("nuclei".into()),
            color: Some(rgb(COLORS[0])),
            window: Some([4000.0, 30000.0]),
            active: true,
        },
        ChannelInfo {
            label: Some("membrane".into()),
            color: Some(rgb(COLORS[1])),
            window: Some([8000.0, 45000.0]),
            active: true,
        },
    ];
    brickray::io::zarr::write_ome_zarr_channels(root, &volume, &info).expect("write the OME-Zarr");
}

/// The library's in-core DVR of `volume` through `styles` for the camera
/// and viewport of a screenshot, over black.
fn library_channels(
    volume: &ChannelVolume,
    styles: &[ChannelStyle],
    frame: VolumeFrame,
    camera: Camera,
    w: u32,
    h: u32,
) -> Vec<u8> {
    library_draw(volume, styles, frame, camera, None, w, h)
}

/// The library's image of `volume` with `styles` (a slice `view` of it with
/// `Some`), `w x h`.
fn library_draw(
    volume: &ChannelVolume,
    styles: &[ChannelStyle],
    frame: VolumeFrame,
    camera: Camera,
    view: Option<brickray::SliceView>,
    w: u32,
    h: u32,
) -> Vec<u8> {
    let gpu = brickray_harness::shared_gpu();
    let mut renderer =
        VolumeRenderer::new(&gpu.device, brickray_harness::target_desc()).expect("renderer");
    renderer
        .set_channel_volume(&gpu.device, &gpu.queue, volume)
        .expect("channel volume");
    renderer.set_channel_styles(styles).expect("styles");
    renderer.set_slice(view);
    let target = brickray_harness::Offscreen::new(&gpu.device, w, h);
    let desc = FrameDesc::new(camera, frame, w, h);
    brickray_harness::draw_frame(gpu, &mut renderer, &target, &desc, Some(wgpu::Color::BLACK))
        .expect("draw");
    target.read_color(gpu)
}

/// Pixels where `color`'s dominant component leads clearly: the channel of
/// that colour shows there (orange-red: red over green and blue; azure:
/// blue over red).
fn pixels_of(shot: &[u8], channel: usize) -> usize {
    shot.chunks(4)
        .filter(|p| {
            let [r, g, b] = [p[0], p[1], p[2]].map(u32::from);
            match channel {
                0 => r > 60 && r > 2 * g && r > 2 * b,
                _ => b > 60 && b > 2 * r,
            }
        })
        .count()
}

#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn a_two_channel_ome_zarr_is_drawn_with_its_omero_styles() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let zarr = dir.path().join("two.ome.zarr");
    write_two_channels(&zarr);
    let out = |name: &str| -> PathBuf { dir.path().join(name) };
    let script = format!(
        "open {zarr}\nbackground 0 0 0\noverlays off\ncamera orbit 20 15 0.9\n\
         wait converged\nwait 2\nscreenshot {both}\nchannel 1 visible off\nwait 2\n\
         screenshot {hidden}\nlayout four\nwait 3\nscreenshot {four}\nquit\n",
        zarr = zarr.display(),
        both = out("both.png").display(),
        hidden = out("hidden.png").display(),
        four = out("four.png").display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(120));

    // The library, independently: the file's channels and default styles.
    let read = brickray::io::read_channels(&zarr, &ReadOptions::default()).expect("read_channels");
    assert_eq!(read.volume.len(), 2);
    let styles = read.styles();
    let d = read.volume.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let side = sidecar_json(&out("both.png"));
    let model: Vec<f32> = side["frame"]["model"]
        .as_array()
        .expect("the frame")
        .iter()
        .map(|v| v.as_f64().expect("a number") as f32)
        .collect();
    assert_eq!(model, frame.model.to_cols_array(), "the viewer's frame");

    let (shot, w, h) = read_png(&out("both.png"));
    let (camera, vw, vh) = sidecar(&out("both.png"));
    assert_eq!((w, h), (vw, vh));
    let lib = library_channels(&read.volume, &styles, frame, camera, w, h);
    let (red, azure) = (pixels_of(&shot, 0), pixels_of(&shot, 1));
    eprintln!("both channels: {red} orange-red, {azure} azure pixels of {w}x{h}");
    assert!(
        red > 200 && azure > 200,
        "both channels' colours show: {red} orange-red, {azure} azure pixels"
    );
    let cmp = brickray_reference::assert_close("viewer-channels", &shot, &lib, w, h, MIN_PSNR_DB)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("two channels vs library: {cmp}");
    // The metric tells the file's styles from the defaults a viewer that
    // ignored them would draw (the palette's colours over the whole range).
    let ignored: Vec<ChannelStyle> = read
        .volume
        .channels()
        .iter()
        .enumerate()
        .map(|(i, v)| ChannelInfo::default().style(i, v.desc().value_range))
        .collect();
    let plain = library_channels(&read.volume, &ignored, frame, camera, w, h);
    let db = brickray_reference::psnr(&shot, &plain);
    assert!(
        db < MIN_PSNR_DB - 10.0,
        "file styles vs defaults: {db:.1} dB"
    );

    // Channel 1 hidden.
    let (hidden, hw, hh) = read_png(&out("hidden.png"));
    assert_eq!((hw, hh), (w, h));
    let mut one = styles.clone();
    one[1].visible = false;
    let lib_hidden = library_channels(&read.volume, &one, frame, camera, w, h);
    assert_eq!(pixels_of(&hidden, 1), 0, "channel 1 is hidden");
    assert!(pixels_of(&hidden, 0) > 200, "channel 0 still shows");
    let cmp = brickray_reference::assert_close(
        "viewer-channels-hidden",
        &hidden,
        &lib_hidden,
        w,
        h,
        MIN_PSNR_DB,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("channel 1 hidden vs library: {cmp}");
    let db = brickray_reference::psnr(&shot, &lib_hidden);
    assert!(db < MIN_PSNR_DB - 10.0, "both vs hidden: {db:.1} dB");

    // The four-view layout: three slices of the channels (channel 1 still
    // hidden), each the library's slice of that view.
    let four = sidecar_json(&out("four.png"));
    let slices = four["slices"].as_array().expect("the slices");
    assert_eq!(slices.len(), 3);
    let (img, fw, _) = read_png(&out("four.png"));
    // Pixels of channel 0 over the slices (a slice may miss its blob).
    let mut shown = 0;
    for (i, sl) in slices.iter().enumerate() {
        let v3 = |v: &serde_json::Value| {
            <[f64; 3]>::try_from(super::anatomy::numbers(v)).expect("three numbers")
        };
        let view = brickray::SliceView {
            centre: v3(&sl["centre"]),
            right: v3(&sl["right"]),
            up: v3(&sl["up"]),
            height: sl["height"].as_f64().expect("height"),
            slab: None,
        };
        let vp = <[u32; 4]>::try_from(
            super::anatomy::numbers(&sl["viewport"])
                .iter()
                .map(|&x| x as u32)
                .collect::<Vec<_>>(),
        )
        .expect("a viewport");
        let got = super::anatomy::crop(&img, fw, vp);
        shown += pixels_of(&got, 0);
        assert_eq!(pixels_of(&got, 1), 0, "slice {i}: channel 1 is hidden");
        let lib = library_draw(&read.volume, &one, frame, camera, Some(view), vp[2], vp[3]);
        let cmp = brickray_reference::assert_close(
            &format!("viewer-channels-slice-{i}"),
            &got,
            &lib,
            vp[2],
            vp[3],
            MIN_PSNR_DB,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        eprintln!("channel slice {i} vs library: {cmp}");
    }
    assert!(shown > 100, "channel 0 shows in {shown} slice pixels");
}

/// The two-channel OME-Zarr streamed (`--in-core-max 0`): every channel
/// streams with the file's styles, and the converged screenshot is the
/// library's in-core image of that view (the streamed cut at the finest
/// level the view needs draws the same samples).
#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn a_two_channel_ome_zarr_streams_with_its_omero_styles() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let zarr = dir.path().join("two.ome.zarr");
    write_two_channels(&zarr);
    let out = dir.path().join("streamed.png");
    let script = format!(
        "open {zarr}\nbackground 0 0 0\noverlays off\ncamera orbit 20 15 0.9\n\
         wait converged\nwait 2\nscreenshot {shot}\nquit\n",
        zarr = zarr.display(),
        shot = out.display(),
    );
    run_script_with(
        dir.path(),
        &script,
        Duration::from_secs(120),
        &["--in-core-max", "0"],
    );
    let read = brickray::io::read_channels(&zarr, &ReadOptions::default()).expect("read_channels");
    let styles = read.styles();
    let d = read.volume.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let (shot, w, h) = read_png(&out);
    let (camera, _, _) = sidecar(&out);
    let side = sidecar_json(&out);
    assert!(
        side["working_set_bricks"].as_u64().is_some_and(|n| n > 0),
        "not streamed: {side}"
    );
    let lib = library_channels(&read.volume, &styles, frame, camera, w, h);
    let (red, azure) = (pixels_of(&shot, 0), pixels_of(&shot, 1));
    assert!(
        red > 200 && azure > 200,
        "both channels' colours show: {red} orange-red, {azure} azure pixels"
    );
    let cmp = brickray_reference::assert_close(
        "viewer-channels-streamed",
        &shot,
        &lib,
        w,
        h,
        MIN_PSNR_DB,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("two streamed channels vs library in core: {cmp}");
}
