//! Multi-channel inputs read whole (`read_channels`): OME-Zarr 0.4 and 0.5
//! with a `c` axis and their `omero` metadata, ImageJ hyperstacks and
//! OME-TIFF, raw + JSON with `"channels"`, single-channel formats as one
//! channel, the channel limit; and the shared sharded nuclei image's `omero`
//! colour and window as its channel info and default style.
#![cfg(all(feature = "zarr", feature = "tiff"))]

mod formats_common;

use brickray_core::channels::ChannelStyle;
use brickray_core::{DType, Volume, VolumeData};
use brickray_io::{
    self as io, CHANNEL_PALETTE, ChannelInfo, DEFAULT_CHANNEL_OPACITY, IoError, ReadChannels,
    ReadOptions,
};
use serde_json::{Value, json};
use std::path::Path;
use tempfile::TempDir;

const DIMS: [u32; 3] = [70, 9, 5];
const SPACING: [f32; 3] = [0.5, 0.25, 2.0];

fn voxels() -> usize {
    DIMS.iter().product::<u32>() as usize
}

/// The base u16 volume: every voxel different along each axis.
fn base() -> Vec<u16> {
    let [nx, ny, nz] = DIMS;
    let mut v = Vec::with_capacity(voxels());
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                v.push(((x * 311 + y * 1303 + z * 9001 + 17) % 60000) as u16);
            }
        }
    }
    v
}

/// Transformed copies of the base: 0 itself, 1 inverted, 2 shifted by one
/// voxel along x (wrapping), 3 halved plus 1000.
fn transformed(k: usize) -> Vec<u16> {
    let b = base();
    let nx = DIMS[0] as usize;
    match k {
        0 => b,
        1 => b.iter().map(|&v| 65535 - v).collect(),
        2 => (0..b.len())
            .map(|i| b[i - i % nx + (i % nx + 1) % nx])
            .collect(),
        3 => b.iter().map(|&v| v / 2 + 1000).collect(),
        _ => b.iter().map(|&v| v ^ 0x5555).collect(),
    }
}

fn volume(data: Vec<u16>) -> Volume {
    Volume::with_data_range(DIMS, SPACING, VolumeData::U16(data)).unwrap()
}

/// Asserts that channel `c` of `got` holds `want`, naming the first voxel
/// that differs.
fn assert_channel(got: &ReadChannels, c: usize, want: &[u16], what: &str) {
    let v = &got.volume.channels()[c];
    assert_eq!(v.dims(), DIMS, "{what}: channel {c} dims");
    let VolumeData::U16(data) = v.data() else {
        panic!("{what}: channel {c} is {:?}", v.desc().dtype);
    };
    assert_eq!(data.len(), want.len(), "{what}: channel {c} length");
    if let Some(i) = (0..want.len()).find(|&i| data[i] != want[i]) {
        panic!(
            "{what}: channel {c} differs at voxel {i}: {} read, {} written",
            data[i], want[i]
        );
    }
    let lo = *want.iter().min().unwrap() as f32;
    let hi = *want.iter().max().unwrap() as f32;
    assert_eq!(v.desc().value_range, [lo, hi], "{what}: channel {c} range");
}

// ---------------------------------------------------------------------------
// OME-Zarr

/// A 2-channel OME-Zarr 0.4 written by `write_ome_zarr_channels` (its
/// `.zattrs` checked as other tools read it) reads back voxel for voxel with
/// the `omero` label, colour, window and `active` written.
#[test]
fn ome_zarr_v04_two_channels_read_back_with_their_omero_metadata() {
    let d = TempDir::new().unwrap();
    let root = d.path().join("two.ome.zarr");
    let want = [transformed(0), transformed(1)];
    let vol = brickray_core::ChannelVolume::new(want.iter().map(|w| volume(w.clone())).collect())
        .unwrap();
    let info = [
        ChannelInfo {
            label: Some("nuclei".into()),
            color: Some([0.0, 1.0, 0.0]),
            window: Some([1000.0, 30000.0]),
            active: true,
        },
        ChannelInfo {
            label: Some("membrane".into()),
            color: Some([1.0, 0.0, 128.0 / 255.0]),
            window: Some([5535.0, 64000.5]),
            active: false,
        },
    ];
    io::zarr::write_ome_zarr_channels(&root, &vol, &info).unwrap();
    // what other tools read: the standard's omero fields
    let attrs: Value =
        serde_json::from_str(&std::fs::read_to_string(root.join(".zattrs")).unwrap()).unwrap();
    let om = &attrs["omero"]["channels"];
    assert_eq!(om[0]["label"], "nuclei");
    assert_eq!(om[0]["color"], "00FF00");
    assert_eq!(om[1]["color"], "FF0080");
    assert_eq!(om[1]["window"]["start"], 5535.0);
    assert_eq!(om[1]["window"]["end"], 64000.5);
    assert_eq!(om[1]["active"], false);
    assert_eq!(attrs["multiscales"][0]["axes"][0]["name"], "c");

    let got = io::read_channels(&root, &ReadOptions::default()).unwrap();
    assert_eq!(got.format, "OME-Zarr");
    assert_eq!(got.volume.len(), 2);
    assert_eq!(got.indices, [0, 1]);
    for (c, w) in want.iter().enumerate() {
        assert_channel(&got, c, w, "v0.4");
    }
    assert_eq!(got.info, info);
    assert!(got.warnings.is_empty(), "{:?}", got.warnings);
    assert_eq!(got.volume.desc().spacing, SPACING);
    let pl = got.placement.expect("OME-Zarr places its image");
    assert_eq!(pl.voxel_to_world([1.0, 1.0, 1.0]), [0.5, 0.25, 2.0]);
    // a single-channel read of channel 1 is the same channel
    let mut one = io::open_with(&root, &ReadOptions::default().channel(Some(1))).unwrap();
    assert_eq!(
        one.read_volume().unwrap(),
        got.volume.channels()[1],
        "single-channel read"
    );
    // the default styles: the file's colour, its window over the channel's
    // range, hidden when inactive
    let styles = got.styles();
    for (c, s) in styles.iter().enumerate() {
        let [lo, hi] = got.volume.channels()[c].desc().value_range;
        let [ws, we] = info[c].window.unwrap();
        let n = |v: f32| ((v as f64 - lo as f64) / (hi as f64 - lo as f64)) as f32;
        let expect = ChannelStyle::window(
            info[c].color.unwrap(),
            [n(ws), n(we)],
            DEFAULT_CHANNEL_OPACITY,
        )
        .visible(c == 0);
        assert_eq!(*s, expect, "channel {c}'s style");
    }
    assert!(styles[0].visible && !styles[1].visible);
}

/// Writes an OME-Zarr 0.5 image (zarr v3, through zarrs) of `data`, an
/// array of `shape` in `chunk`s with axes named by `axes`, and the group
/// attributes `ome` (the `multiscales` is added).
#[allow(clippy::too_many_arguments)]
fn zarr_v05<T: zarrs::array::Element>(
    root: &Path,
    axes: &[&str],
    shape: Vec<u64>,
    chunk: Vec<u64>,
    dt: zarrs::array::DataType,
    fill: impl Into<zarrs::array::builder::ArrayBuilderFillValue>,
    data: &[T],
    mut ome: Value,
) {
    use std::sync::Arc;
    use zarrs::array::ArrayBuilder;
    use zarrs::filesystem::FilesystemStore;
    std::fs::create_dir_all(root).unwrap();
    let axes: Vec<Value> = axes
        .iter()
        .map(|&a| {
            let kind = match a {
                "c" => "channel",
                "t" => "time",
                _ => "space",
            };
            json!({"name": a, "type": kind})
        })
        .collect();
    let n = axes.len();
    let mut scale = vec![1.0; n];
    scale[n - 3..].copy_from_slice(&[SPACING[2] as f64, SPACING[1] as f64, SPACING[0] as f64]);
    ome["version"] = json!("0.5");
    ome["multiscales"] = json!([{
        "axes": axes,
        "datasets": [{"path": "s0", "coordinateTransformations": [{"type": "scale", "scale": scale}]}]
    }]);
    let group = json!({"zarr_format": 3, "node_type": "group", "attributes": {"ome": ome}});
    std::fs::write(root.join("zarr.json"), group.to_string()).unwrap();
    let store = Arc::new(FilesystemStore::new(root).unwrap());
    let array = ArrayBuilder::new(shape, chunk, dt, fill)
        .build(store, "/s0")
        .unwrap();
    array.store_metadata().unwrap();
    array.store_array_subset(&array.subset_all(), data).unwrap();
}

/// The four transformed volumes as one c, z, y, x array (channel slowest),
/// repeated for each of `times` time points with `+ t` added.
fn czyx(channels: usize, times: u16) -> Vec<u16> {
    (0..times)
        .flat_map(|t| {
            (0..channels)
                .flat_map(move |c| transformed(c).into_iter().map(move |v| v.wrapping_add(t)))
        })
        .collect()
}

/// A 4-channel OME-Zarr 0.5 with a time axis and chunks that hold two
/// channels each: every channel of the chosen time point reads back voxel
/// for voxel; its `omero` fields are read from `attributes.ome`, a malformed
/// colour and window are ignored with a warning (the read does not fail),
/// a channel the omero list leaves out has the defaults; a selection reads
/// the channels it names, in its order.
#[test]
fn ome_zarr_v05_four_channels_with_time_and_a_selection() {
    let d = TempDir::new().unwrap();
    let root = d.path().join("four.ome.zarr");
    let [nx, ny, nz] = DIMS.map(u64::from);
    let omero = json!({"channels": [
        {"label": "a", "color": "FF0000", "window": {"start": 100, "end": 200, "min": 0, "max": 65535}, "active": true},
        {"label": "b", "color": "0000FF", "window": {"start": 0, "end": 65535}, "active": false},
        {"label": "c", "color": "not a colour", "window": {"start": "low", "end": 9}},
    ]});
    zarr_v05(
        &root,
        &["t", "c", "z", "y", "x"],
        vec![2, 4, nz, ny, nx],
        vec![1, 2, 2, 4, 32],
        zarrs::array::data_type::uint16(),
        0u16,
        &czyx(4, 2),
        json!({"omero": omero}),
    );
    let got = io::read_channels(&root, &ReadOptions::default().time(Some(1))).unwrap();
    assert_eq!(got.volume.len(), 4);
    for c in 0..4 {
        let want: Vec<u16> = transformed(c).iter().map(|v| v + 1).collect();
        assert_channel(&got, c, &want, "v0.5 t=1");
    }
    assert_eq!(
        got.info[0],
        ChannelInfo {
            label: Some("a".into()),
            color: Some([1.0, 0.0, 0.0]),
            window: Some([100.0, 200.0]),
            active: true
        }
    );
    assert_eq!(
        got.info[1],
        ChannelInfo {
            label: Some("b".into()),
            color: Some([0.0, 0.0, 1.0]),
            window: Some([0.0, 65535.0]),
            active: false
        }
    );
    assert_eq!(
        got.info[2],
        ChannelInfo {
            label: Some("c".into()),
            ..Default::default()
        }
    );
    assert_eq!(got.info[3], ChannelInfo::default());
    let w = &got.warnings;
    assert!(w.iter().any(|l| l.contains("channel 2's color")), "{w:?}");
    assert!(w.iter().any(|l| l.contains("channel 2's window")), "{w:?}");
    assert!(
        w.iter().any(|l| l.contains("omero lists 3 channels")),
        "{w:?}"
    );
    // defaults: a channel without colour takes the palette's by index
    let s3 = got.info[3].style(3, [0.0, 1.0]);
    assert_eq!(
        s3,
        ChannelStyle::window(CHANNEL_PALETTE[3], [0.0, 1.0], DEFAULT_CHANNEL_OPACITY)
    );
    assert_eq!(CHANNEL_PALETTE[3], [1.0, 1.0, 0.0]);

    // time point 0, channels 3 and 1 in that order
    let opts = ReadOptions::default().channels(Some(vec![3, 1]));
    let got = io::read_channels(&root, &opts).unwrap();
    assert_eq!(got.indices, [3, 1]);
    assert_channel(&got, 0, &transformed(3), "selection");
    assert_channel(&got, 1, &transformed(1), "selection");
    assert_eq!(got.info[0], ChannelInfo::default());
    assert_eq!(got.info[1].label.as_deref(), Some("b"));
    // the single-channel read is unchanged by the selection
    let mut one = io::open_with(&root, &opts.clone().channel(Some(2))).unwrap();
    let v = one.read_volume().unwrap();
    assert_eq!(v.data(), &VolumeData::U16(transformed(2)));
}

/// A 5-channel image read without a selection is a typed error naming the
/// count and the maximum; a selection of up to 4 reads; a selection of 5,
/// an empty one or one naming a channel the image lacks are typed errors.
#[test]
fn five_channels_are_a_typed_error_unless_selected() {
    let d = TempDir::new().unwrap();
    let root = d.path().join("five.ome.zarr");
    let [nx, ny, nz] = DIMS.map(u64::from);
    zarr_v05(
        &root,
        &["c", "z", "y", "x"],
        vec![5, nz, ny, nx],
        vec![1, nz, ny, nx],
        zarrs::array::data_type::uint16(),
        0u16,
        &czyx(5, 1),
        json!({}),
    );
    let e = io::read_channels(&root, &ReadOptions::default()).unwrap_err();
    assert!(
        matches!(
            e,
            IoError::TooManyChannels {
                count: 5,
                max: 4,
                ..
            }
        ),
        "{e:?}"
    );
    let msg = e.to_string();
    assert!(msg.contains('5') && msg.contains('4'), "{msg}");
    let got = io::read_channels(&root, &ReadOptions::default().channels(Some(vec![4, 0]))).unwrap();
    assert_channel(&got, 0, &transformed(4), "channel 4");
    assert_channel(&got, 1, &transformed(0), "channel 0");
    let e = io::read_channels(
        &root,
        &ReadOptions::default().channels(Some(vec![0, 1, 2, 3, 4])),
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            IoError::TooManyChannels {
                count: 5,
                max: 4,
                ..
            }
        ),
        "{e:?}"
    );
    for pick in [vec![], vec![5]] {
        let e = io::read_channels(&root, &ReadOptions::default().channels(Some(pick.clone())))
            .unwrap_err();
        assert!(
            matches!(
                e,
                IoError::NoSuchChoice {
                    what: "channel",
                    ..
                }
            ),
            "{pick:?}: {e:?}"
        );
    }
    // the same limit for a raw sidecar
    let raw: Vec<u8> = czyx(5, 1).iter().flat_map(|v| v.to_le_bytes()).collect();
    let json = raw_sidecar(d.path(), "five", 5, &raw);
    let e = io::read_channels(&json, &ReadOptions::default()).unwrap_err();
    assert!(
        matches!(
            e,
            IoError::TooManyChannels {
                count: 5,
                max: 4,
                ..
            }
        ),
        "{e:?}"
    );
}

/// Channels whose sample types the readers choose differently (u32 data
/// that fits u16 in one channel, not in the other) are all read as f32,
/// exactly, and the notes say so.
#[test]
fn channels_of_different_narrowed_types_are_read_as_f32() {
    let d = TempDir::new().unwrap();
    let root = d.path().join("u32.ome.zarr");
    let [nx, ny, nz] = DIMS.map(u64::from);
    let small: Vec<u32> = base().iter().map(|&v| v as u32).collect();
    let large: Vec<u32> = base().iter().map(|&v| v as u32 * 3 + 70000).collect();
    let data: Vec<u32> = small.iter().chain(&large).copied().collect();
    zarr_v05(
        &root,
        &["c", "z", "y", "x"],
        vec![2, nz, ny, nx],
        vec![1, nz, ny, nx],
        zarrs::array::data_type::uint32(),
        0u32,
        &data,
        json!({}),
    );
    let got = io::read_channels(&root, &ReadOptions::default()).unwrap();
    assert_eq!(got.volume.dtype(), DType::F32);
    for (c, want) in [small, large].iter().enumerate() {
        let v = &got.volume.channels()[c];
        let want: Vec<f32> = want.iter().map(|&x| x as f32).collect();
        assert_eq!(v.data(), &VolumeData::F32(want), "channel {c}");
    }
    assert!(
        got.notes.iter().any(|n| n.contains("all read as f32")),
        "{:?}",
        got.notes
    );
}

// ---------------------------------------------------------------------------
// TIFF

/// Writes a u16 TIFF of `pages` (each `DIMS[0] x DIMS[1]`), with
/// `description` as the first page's ImageDescription (as ImageJ writes it)
/// and resolution tags of `res` pixels per unit.
fn tiff_pages(path: &Path, pages: &[Vec<u16>], description: Option<&str>, res: f64) {
    use tiff::encoder::{Rational, TiffEncoder, colortype};
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut enc = TiffEncoder::new(&mut f).unwrap();
    for (i, page) in pages.iter().enumerate() {
        let mut im = enc
            .new_image::<colortype::Gray16>(DIMS[0], DIMS[1])
            .unwrap();
        if let Some(desc) = description {
            if i == 0 {
                im.encoder()
                    .write_tag(tiff::tags::Tag::ImageDescription, desc)
                    .unwrap();
            }
            let r = Rational {
                n: (res * 1000.0).round() as u32,
                d: 1000,
            };
            im.resolution(tiff::tags::ResolutionUnit::None, r);
        }
        im.write_data(page).unwrap();
    }
}

/// Slice `z` of `v`.
fn slice(v: &[u16], z: usize) -> Vec<u16> {
    let n = (DIMS[0] * DIMS[1]) as usize;
    v[z * n..(z + 1) * n].to_vec()
}

/// An ImageJ hyperstack of 2 channels (pages channel fastest, then z, as
/// ImageJ saves them) reads back voxel for voxel, with ImageJ's spacing; a
/// single-channel read of channel 1 is the same; the same pages without the
/// description are a plain stack: one channel of every page.
#[test]
fn imagej_hyperstack_reads_every_channel() {
    let d = TempDir::new().unwrap();
    let p = d.path().join("hyper.tif");
    let want = [transformed(0), transformed(1)];
    let nz = DIMS[2] as usize;
    let pages: Vec<Vec<u16>> = (0..nz)
        .flat_map(|z| want.iter().map(move |w| slice(w, z)))
        .collect();
    let desc = format!(
        "ImageJ=1.54f\nimages={}\nchannels=2\nslices={nz}\nhyperstack=true\nmode=composite\nunit=micron\nspacing=2.0\nloop=false\nmin=0.0\nmax=65535.0\n",
        pages.len()
    );
    tiff_pages(&p, &pages, Some(&desc), 4.0);
    let got = io::read_channels(&p, &ReadOptions::default()).unwrap();
    assert_eq!(got.format, "TIFF");
    assert_eq!(got.volume.len(), 2);
    for (c, w) in want.iter().enumerate() {
        assert_channel(&got, c, w, "hyperstack");
    }
    assert_eq!(got.volume.desc().spacing, [0.25, 0.25, 2.0]);
    assert_eq!(got.info, vec![ChannelInfo::default(); 2]);
    let mut one = io::open_with(&p, &ReadOptions::default().channel(Some(1))).unwrap();
    assert_eq!(one.read_volume().unwrap(), got.volume.channels()[1]);
    // channels 2..: none
    let e = io::read_channels(&p, &ReadOptions::default().channels(Some(vec![2]))).unwrap_err();
    assert!(matches!(e, IoError::NoSuchChoice { .. }), "{e:?}");

    // no metadata: a plain multi-page stack is one channel of all pages
    let plain = d.path().join("plain.tif");
    tiff_pages(&plain, &pages, None, 1.0);
    let got = io::read_channels(&plain, &ReadOptions::default()).unwrap();
    assert_eq!(got.volume.len(), 1);
    assert_eq!(got.volume.dims(), [DIMS[0], DIMS[1], 2 * DIMS[2]]);
    let VolumeData::U16(data) = got.volume.channels()[0].data() else {
        panic!("u16")
    };
    assert_eq!(data, &pages.concat());
}

/// An OME-TIFF of 2 channels in the order XYZCT (z fastest, then channel)
/// reads back voxel for voxel, with the names and colours of its `Channel`
/// elements.
#[test]
fn ome_tiff_channels_in_their_dimension_order() {
    let d = TempDir::new().unwrap();
    let p = d.path().join("two.ome.tif");
    let want = [transformed(2), transformed(3)];
    let nz = DIMS[2] as usize;
    let pages: Vec<Vec<u16>> = want
        .iter()
        .flat_map(|w| (0..nz).map(move |z| slice(w, z)))
        .collect();
    let xml = format!(
        r#"<?xml version="1.0" encoding="UTF-8"?><OME xmlns="http://www.openmicroscopy.org/Schemas/OME/2016-06"><Image ID="Image:0"><Pixels ID="Pixels:0" DimensionOrder="XYZCT" Type="uint16" SizeX="{}" SizeY="{}" SizeZ="{nz}" SizeC="2" SizeT="1" PhysicalSizeX="0.5" PhysicalSizeY="0.25" PhysicalSizeZ="2"><Channel ID="Channel:0:0" Name="DAPI" Color="65535" SamplesPerPixel="1"/><Channel ID="Channel:0:1" Name="GFP" Color="16711935" SamplesPerPixel="1"/><TiffData/></Pixels></Image></OME>"#,
        DIMS[0], DIMS[1]
    );
    tiff_pages(&p, &pages, Some(&xml), 1.0);
    let got = io::read_channels(&p, &ReadOptions::default()).unwrap();
    assert_eq!(got.volume.len(), 2);
    for (c, w) in want.iter().enumerate() {
        assert_channel(&got, c, w, "OME-TIFF XYZCT");
    }
    assert_eq!(got.volume.desc().spacing, SPACING);
    assert_eq!(got.info[0].label.as_deref(), Some("DAPI"));
    assert_eq!(got.info[0].color, Some([0.0, 0.0, 1.0]));
    assert_eq!(got.info[1].label.as_deref(), Some("GFP"));
    assert_eq!(got.info[1].color, Some([0.0, 1.0, 0.0]));
    assert!(got.info.iter().all(|i| i.window.is_none() && i.active));
}

// ---------------------------------------------------------------------------
// raw + JSON, single-channel formats

/// Writes `name.raw` and its sidecar (u16, `DIMS`, `SPACING`, `channels`).
fn raw_sidecar(dir: &Path, name: &str, channels: u64, raw: &[u8]) -> std::path::PathBuf {
    std::fs::write(dir.join(format!("{name}.raw")), raw).unwrap();
    let json = dir.join(format!("{name}.json"));
    let sc = json!({"dims": DIMS, "dtype": "u16", "spacing": SPACING, "byte_order": "little", "channels": channels});
    std::fs::write(&json, sc.to_string()).unwrap();
    json
}

/// A raw file of 3 planar channels (channel slowest) reads back voxel for
/// voxel; `channel` picks one for a single-channel read; a file of the wrong
/// size is `SizeMismatch` naming the size 3 channels need; a `channels`
/// that is not a positive integer is `BadHeader`.
#[test]
fn raw_sidecar_with_three_planar_channels() {
    let d = TempDir::new().unwrap();
    let raw: Vec<u8> = czyx(3, 1).iter().flat_map(|v| v.to_le_bytes()).collect();
    let json = raw_sidecar(d.path(), "three", 3, &raw);
    let got = io::read_channels(&json, &ReadOptions::default()).unwrap();
    assert_eq!(got.format, "raw");
    assert_eq!(got.volume.len(), 3);
    for c in 0..3 {
        assert_channel(&got, c, &transformed(c), "raw");
    }
    assert_eq!(got.volume.desc().spacing, SPACING);
    assert!(got.placement.is_none());
    // `.raw` names the same input
    let via_raw = io::read_channels(d.path().join("three.raw"), &ReadOptions::default()).unwrap();
    assert_eq!(via_raw.volume, got.volume);
    let mut one = io::open_with(&json, &ReadOptions::default().channel(Some(2))).unwrap();
    assert_eq!(one.read_volume().unwrap(), got.volume.channels()[2]);
    let e = io::open_with(&json, &ReadOptions::default().channel(Some(3)))
        .err()
        .expect("channel 3 of 3 opened");
    assert!(matches!(e, IoError::NoSuchChoice { .. }), "{e:?}");
    let listed = io::list(&json, &ReadOptions::default()).unwrap();
    assert_eq!(listed.len(), 3);

    // one sample short, or a fourth channel too many
    let bytes = (voxels() * 2) as u64;
    let mut long = raw.clone();
    long.resize(raw.len() + 2 * voxels(), 0);
    for wrong in [&raw[..raw.len() - 2], &long[..]] {
        std::fs::write(d.path().join("three.raw"), wrong).unwrap();
        let e = io::read_channels(&json, &ReadOptions::default()).unwrap_err();
        match e {
            IoError::SizeMismatch {
                expected, actual, ..
            } => {
                assert_eq!(expected, 3 * bytes);
                assert_eq!(actual, wrong.len() as u64);
            }
            other => panic!("{} bytes: {other:?}", wrong.len()),
        }
    }
    for bad in [json!(0), json!(-1), json!(2.5), json!("3")] {
        let sc = json!({"dims": DIMS, "dtype": "u16", "channels": bad});
        std::fs::write(&json, sc.to_string()).unwrap();
        let e = io::read_channels(&json, &ReadOptions::default()).unwrap_err();
        assert!(matches!(e, IoError::BadHeader { .. }), "{bad}: {e:?}");
    }
}

/// A single-channel format (NRRD; a raw sidecar without `channels`) reads
/// as one channel with no metadata, its volume the single read's.
#[test]
fn single_channel_formats_are_one_channel() {
    let d = TempDir::new().unwrap();
    let b = base();
    let bytes: Vec<u8> = b.iter().flat_map(|v| v.to_le_bytes()).collect();
    let nrrd = d.path().join("one.nrrd");
    let mut f = format!(
        "NRRD0004\ntype: ushort\ndimension: 3\nsizes: {} {} {}\nencoding: raw\nendian: little\nspacings: 0.5 0.25 2\n\n",
        DIMS[0], DIMS[1], DIMS[2]
    )
    .into_bytes();
    f.extend_from_slice(&bytes);
    std::fs::write(&nrrd, f).unwrap();
    let got = io::read_channels(&nrrd, &ReadOptions::default()).unwrap();
    assert_eq!(got.format, "NRRD");
    assert_eq!(got.volume.len(), 1);
    assert_channel(&got, 0, &b, "NRRD");
    assert_eq!(got.info, [ChannelInfo::default()]);
    assert_eq!(got.volume.channels()[0], io::read_volume(&nrrd).unwrap());
    // selecting channel 0 is the same; channel 1 does not exist
    let sel = io::read_channels(&nrrd, &ReadOptions::default().channels(Some(vec![0]))).unwrap();
    assert_eq!(sel.volume, got.volume);
    let e = io::read_channels(&nrrd, &ReadOptions::default().channels(Some(vec![1]))).unwrap_err();
    assert!(matches!(e, IoError::NoSuchChoice { .. }), "{e:?}");

    let json = d.path().join("plain.json");
    std::fs::write(d.path().join("plain.raw"), &bytes).unwrap();
    std::fs::write(
        &json,
        json!({"dims": DIMS, "dtype": "u16", "spacing": SPACING}).to_string(),
    )
    .unwrap();
    let got = io::read_channels(&json, &ReadOptions::default()).unwrap();
    assert_eq!(got.volume.len(), 1);
    assert_channel(&got, 0, &b, "raw, no channels");
    // a label map is not a channel
    std::fs::write(
        &json,
        json!({"dims": DIMS, "dtype": "u16", "kind": "labels"}).to_string(),
    )
    .unwrap();
    let e = io::read_channels(&json, &ReadOptions::default()).unwrap_err();
    assert!(matches!(e, IoError::Channels { .. }), "{e:?}");
}

// ---------------------------------------------------------------------------
// The shared sharded nuclei image

/// `cells3d_nuclei_sharded_v05.ome.zarr` has one channel whose `omero` says
/// label `nuclei`, colour `00FF00`, window start 2000 and end 40000, active:
/// its channel info, and its default style (green through 2000..40000 of
/// its value range 0..65535), read with the channel's voxels equal to the
/// single-channel read's.
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn shared_nuclei_image_omero_gives_its_channel_info_and_style() {
    let Some(formats) = formats_common::formats_dir() else {
        return;
    };
    let p = formats.join("ome-zarr/cells3d_nuclei_sharded_v05.ome.zarr");
    let got = io::read_channels(&p, &ReadOptions::default()).unwrap();
    assert_eq!(got.volume.len(), 1);
    assert_eq!(got.volume.dims(), [256, 256, 60]);
    assert_eq!(
        got.info,
        [ChannelInfo {
            label: Some("nuclei".into()),
            color: Some([0.0, 1.0, 0.0]),
            window: Some([2000.0, 40000.0]),
            active: true,
        }]
    );
    assert!(got.warnings.is_empty(), "{:?}", got.warnings);
    let v = &got.volume.channels()[0];
    assert_eq!(v.desc().value_range, [0.0, 65535.0]);
    assert_eq!(*v, io::read_volume(&p).unwrap());
    let style = got.info[0].style(0, v.desc().value_range);
    let expect = ChannelStyle::window(
        [0.0, 1.0, 0.0],
        [(2000.0 / 65535.0f64) as f32, (40000.0 / 65535.0f64) as f32],
        0.5,
    );
    assert_eq!(style, expect);
    assert!(style.visible);
    let mid = 0.5 * ((2000.0 / 65535.0f64) as f32 + (40000.0 / 65535.0f64) as f32);
    assert_eq!(style.isovalue, mid);
    assert_eq!(got.styles(), [expect]);
    // the window's ends in the style's transfer function: transparent at
    // 2000, 0.5 at 40000 and above
    let a = |raw: f64| style.tf.lookup(raw / 65535.0)[3];
    assert!(a(1000.0) < 1e-3, "{}", a(1000.0));
    assert!((a(50000.0) - 0.5).abs() < 1e-3, "{}", a(50000.0));
    assert!((a(21000.0) - 0.25).abs() < 0.01, "{}", a(21000.0));
}

/// The finest level that fits a budget: the shared sharded nuclei image has
/// levels of 256x256x60 and 128x128x60 u16 voxels, one channel.
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn the_finest_level_within_a_budget_is_found() {
    let Some(formats) = formats_common::formats_dir() else {
        return;
    };
    let p = formats.join("ome-zarr/cells3d_nuclei_sharded_v05.ome.zarr");
    let image = brickray_io::zarr::OmeZarr::open(&p).unwrap();
    assert_eq!(image.sample_bytes(), 2);
    assert_eq!(image.level_dims(0), Some([256, 256, 60]));
    assert_eq!(image.level_dims(1), Some([128, 128, 60]));
    let s0 = 256 * 256 * 60 * 2;
    assert_eq!(image.level_fitting(1, s0, 256), Some(0));
    assert_eq!(image.level_fitting(1, s0 - 1, 256), Some(1));
    assert_eq!(image.level_fitting(4, s0, 256), Some(1));
    assert_eq!(image.level_fitting(1, s0, 255), Some(1));
    assert_eq!(image.level_fitting(1, 1000, 256), None);
    assert_eq!(image.level_fitting(1, u64::MAX, 100), None);
}
