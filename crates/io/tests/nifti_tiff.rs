//! NIfTI and TIFF: the shared fixtures decode voxel for voxel to their raw
//! volumes; synthesized variants (NIfTI-2, header/image pairs, big-endian,
//! scaled and converted types, unpadded slice names) and lying headers.
#![cfg(all(feature = "nifti", feature = "tiff"))]

mod formats_common;

use brickray_core::DType;
use brickray_io::{self as io, IoError, ReadOptions};
use formats_common::*;
use std::path::Path;
use tempfile::TempDir;

#[test]
#[allow(clippy::needless_range_loop)]
fn nifti_fixture_decodes_with_its_affine() {
    let Some(dir) = formats_dir() else { return };
    let t = truth("pycortex_s1_t1_mri");
    let p = dir.join("nifti/pycortex_s1_t1.nii.gz");
    let mut r = io::open(&p).unwrap();
    assert_eq!(r.format(), "NIfTI-1");
    assert_eq!(r.desc().dims, t.desc.dims);
    assert_eq!(r.desc().dtype, t.desc.dtype);
    assert_spacing(r.desc().spacing, t.desc.spacing, "nifti");
    assert_same_voxels(&read_by_slabs(r.as_mut(), 37), &t, "nifti");
    // placement: the sidecar's affine (FreeSurfer LIA), not a mirrored one
    let pl = r.placement().expect("NIfTI has a placement");
    assert_eq!(pl.space, "RAS");
    // FreeSurfer's conformed order.
    assert_eq!(pl.orientation().expect("anatomical").code(), "LIA");
    let want = t.json["affine"].as_array().unwrap();
    for i in 0..4 {
        for j in 0..4 {
            let w = want[i][j].as_f64().unwrap();
            assert!(
                (pl.affine[i][j] - w).abs() < 1e-4,
                "affine[{i}][{j}] = {}, sidecar {w}",
                pl.affine[i][j]
            );
        }
    }
    // the frame puts voxel centres where the affine says
    let f = pl.frame(r.desc().dims);
    f.validate().unwrap();
    let n = r.desc().dims.map(|d| d as f32);
    let tex = glam::Vec3::new(10.5 / n[0], 20.5 / n[1], 30.5 / n[2]);
    let w = f.model.transform_point3(tex);
    let e = pl.voxel_to_world([10.0, 20.0, 30.0]);
    assert!((w - glam::Vec3::new(e[0] as f32, e[1] as f32, e[2] as f32)).length() < 1e-3);
}

// ---------------------------------------------------------------------------
// Synthesized NIfTI files.

#[allow(clippy::too_many_arguments)]
/// A NIfTI header (version 1 or 2) for `dims` of `datatype`, either byte order.
fn nifti_header(
    version: u8,
    be: bool,
    dims: &[i64],
    datatype: i16,
    bitpix: i16,
    slope: f64,
    inter: f64,
    single: bool,
) -> Vec<u8> {
    let mut b = vec![0u8; if version == 1 { 348 } else { 540 }];
    fn put<const N: usize>(b: &mut [u8], at: usize, mut v: [u8; N], be: bool) {
        if be {
            v.reverse();
        }
        b[at..at + N].copy_from_slice(&v);
    }
    let pix = [1.0f64, 0.5, 0.75, 2.0, 1.0, 1.0, 1.0, 1.0];
    if version == 1 {
        put(&mut b, 0, 348i32.to_le_bytes(), be);
        put(&mut b, 40, (dims.len() as i16).to_le_bytes(), be);
        for (i, d) in dims.iter().enumerate() {
            put(&mut b, 42 + 2 * i, (*d as i16).to_le_bytes(), be);
        }
        put(&mut b, 70, datatype.to_le_bytes(), be);
        put(&mut b, 72, bitpix.to_le_bytes(), be);
        for (i, p) in pix.iter().enumerate() {
            put(&mut b, 76 + 4 * i, (*p as f32).to_le_bytes(), be);
        }
        put(
            &mut b,
            108,
            if single { 352f32 } else { 0.0 }.to_le_bytes(),
            be,
        );
        put(&mut b, 112, (slope as f32).to_le_bytes(), be);
        put(&mut b, 116, (inter as f32).to_le_bytes(), be);
        // qform: 180 degrees about z (b=c=0, d=1): x and y flipped
        put(&mut b, 252, 1i16.to_le_bytes(), be);
        put(&mut b, 264, 1f32.to_le_bytes(), be);
        put(&mut b, 268, 5f32.to_le_bytes(), be);
        b[344..348].copy_from_slice(if single { b"n+1\0" } else { b"ni1\0" });
    } else {
        put(&mut b, 0, 540i32.to_le_bytes(), be);
        b[4..12].copy_from_slice(if single {
            b"n+2\0\r\n\x1a\n"
        } else {
            b"ni2\0\r\n\x1a\n"
        });
        put(&mut b, 12, datatype.to_le_bytes(), be);
        put(&mut b, 14, bitpix.to_le_bytes(), be);
        put(&mut b, 16, (dims.len() as i64).to_le_bytes(), be);
        for (i, d) in dims.iter().enumerate() {
            put(&mut b, 24 + 8 * i, d.to_le_bytes(), be);
        }
        for (i, p) in pix.iter().enumerate() {
            put(&mut b, 104 + 8 * i, p.to_le_bytes(), be);
        }
        put(
            &mut b,
            168,
            if single { 544i64 } else { 0 }.to_le_bytes(),
            be,
        );
        put(&mut b, 176, slope.to_le_bytes(), be);
        put(&mut b, 184, inter.to_le_bytes(), be);
        // sform: a plain scaling with an offset
        put(&mut b, 348, 2i32.to_le_bytes(), be);
        put(&mut b, 400, 0.5f64.to_le_bytes(), be);
        put(&mut b, 424, (-3f64).to_le_bytes(), be);
        put(&mut b, 440, 0.75f64.to_le_bytes(), be);
        put(&mut b, 480, 2.0f64.to_le_bytes(), be);
    }
    if single {
        b.resize(if version == 1 { 352 } else { 544 }, 0);
    }
    b
}

fn write(p: &Path, bytes: &[u8]) {
    std::fs::write(p, bytes).unwrap();
}

#[test]
fn nifti_versions_types_and_byte_orders() {
    let d = TempDir::new().unwrap();
    let dims = [5i64, 4, 3];
    let n = 60usize;
    // (datatype, bitpix, encode value k, expected dtype, expected value of k)
    type Enc = fn(i64, bool) -> Vec<u8>;
    let cases: [(i16, i16, Enc, DType); 5] = [
        (256, 8, |k, _| vec![(k as i8 - 30) as u8], DType::I16),
        (
            512,
            16,
            |k, be| {
                if be {
                    (k as u16 * 700).to_be_bytes().to_vec()
                } else {
                    (k as u16 * 700).to_le_bytes().to_vec()
                }
            },
            DType::U16,
        ),
        (
            8,
            32,
            |k, be| {
                if be {
                    (k as i32 - 10).to_be_bytes().to_vec()
                } else {
                    (k as i32 - 10).to_le_bytes().to_vec()
                }
            },
            DType::I16,
        ),
        (
            768,
            32,
            |k, be| {
                if be {
                    (k as u32 * 100_000).to_be_bytes().to_vec()
                } else {
                    (k as u32 * 100_000).to_le_bytes().to_vec()
                }
            },
            DType::F32,
        ),
        (
            64,
            64,
            |k, be| {
                if be {
                    (k as f64 * 0.25).to_be_bytes().to_vec()
                } else {
                    (k as f64 * 0.25).to_le_bytes().to_vec()
                }
            },
            DType::F32,
        ),
    ];
    let expect = |dt: i16, k: i64| -> f64 {
        match dt {
            256 => (k as i8 - 30) as f64,
            512 => (k * 700) as f64,
            8 => (k - 10) as f64,
            768 => (k * 100_000) as f64,
            _ => k as f64 * 0.25,
        }
    };
    for version in [1u8, 2] {
        for be in [false, true] {
            for (dt, bits, enc, want) in cases {
                for single in [true, false] {
                    let data: Vec<u8> = (0..n as i64).flat_map(|k| enc(k, be)).collect();
                    let h = nifti_header(version, be, &dims, dt, bits, 0.0, 0.0, single);
                    let name = format!("v{version}_{be}_{dt}_{single}");
                    let p = if single {
                        let p = d.path().join(format!("{name}.nii"));
                        write(&p, &[h, data].concat());
                        p
                    } else {
                        write(&d.path().join(format!("{name}.img")), &data);
                        let p = d.path().join(format!("{name}.hdr"));
                        write(&p, &h);
                        p
                    };
                    let mut r = io::open(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
                    assert_eq!(r.desc().dtype, want, "{name}");
                    assert_eq!(r.desc().dims, [5, 4, 3], "{name}");
                    assert_eq!(r.desc().spacing, [0.5, 0.75, 2.0], "{name}");
                    let v = r.read_volume().unwrap();
                    for k in 0..n {
                        assert_eq!(
                            v.data().get(k) as f64,
                            expect(dt, k as i64),
                            "{name} voxel {k}"
                        );
                    }
                    let a = r.placement().unwrap().affine;
                    if version == 1 {
                        // qform 180 degrees about z: x and y mirrored
                        assert_eq!(a[0][0], -0.5, "{name}");
                        assert_eq!(a[1][1], -0.75, "{name}");
                        assert_eq!(a[2][2], 2.0, "{name}");
                        assert_eq!(a[0][3], 5.0, "{name}");
                    } else {
                        assert_eq!(
                            (a[0][0], a[0][3], a[1][1], a[2][2]),
                            (0.5, -3.0, 0.75, 2.0),
                            "{name}"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn nifti_scaling_gzip_and_time_points() {
    let d = TempDir::new().unwrap();
    // u16 with an integer rescale (CT-like): exact i16
    let data: Vec<u8> = (0..60u16).flat_map(|k| (k * 50).to_le_bytes()).collect();
    let h = nifti_header(1, false, &[5, 4, 3], 512, 16, 1.0, -1024.0, true);
    let p = d.path().join("ct.nii");
    write(&p, &[h, data.clone()].concat());
    let v = io::read_volume(&p).unwrap();
    assert_eq!(v.desc().dtype, DType::I16);
    assert_eq!(v.data().get(7), 7.0 * 50.0 - 1024.0);
    // a fractional slope: f32
    let h = nifti_header(1, false, &[5, 4, 3], 512, 16, 0.5, 1.0, true);
    let p = d.path().join("frac.nii.gz");
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    std::io::Write::write_all(&mut gz, &[h, data.clone()].concat()).unwrap();
    write(&p, &gz.finish().unwrap());
    let v = io::read_volume(&p).unwrap();
    assert_eq!(v.desc().dtype, DType::F32);
    assert_eq!(v.data().get(7), 7.0 * 50.0 * 0.5 + 1.0);
    // 4D: time point 1 selected
    let data4: Vec<u8> = (0..120u16).flat_map(|k| k.to_le_bytes()).collect();
    let h = nifti_header(1, false, &[5, 4, 3, 2], 512, 16, 0.0, 0.0, true);
    let p = d.path().join("t.nii");
    write(&p, &[h, data4].concat());
    let mut r = io::open_with(&p, &ReadOptions::default().time(Some(1))).unwrap();
    assert_eq!(r.read_volume().unwrap().data().get(0), 60.0);
    let e = io::open_with(&p, &ReadOptions::default().time(Some(2)))
        .err()
        .unwrap();
    assert!(
        matches!(
            e,
            IoError::NoSuchChoice {
                what: "time point",
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn nifti_lying_headers_are_typed_errors() {
    let d = TempDir::new().unwrap();
    let data: Vec<u8> = vec![7u8; 60];
    let ok = nifti_header(1, false, &[5, 4, 3], 2, 8, 0.0, 0.0, true);
    let case = |name: &str, bytes: Vec<u8>| -> IoError {
        let p = d.path().join(format!("{name}.nii"));
        write(&p, &bytes);
        let e = io::open(&p)
            .err()
            .unwrap_or_else(|| panic!("{name} opened"));
        assert!(
            e.to_string().contains(&p.display().to_string()),
            "{name}: {e}"
        );
        e
    };
    // dims larger than the data
    let mut h = ok.clone();
    h[42..44].copy_from_slice(&500i16.to_le_bytes());
    assert!(matches!(
        case("big", [h, data.clone()].concat()),
        IoError::Truncated { .. }
    ));
    // truncated data
    assert!(matches!(
        case("short", [ok.clone(), data[..30].to_vec()].concat()),
        IoError::Truncated { .. }
    ));
    // bitpix disagreeing with datatype
    let mut h = ok.clone();
    h[72..74].copy_from_slice(&16i16.to_le_bytes());
    assert!(matches!(
        case("bitpix", [h, data.clone()].concat()),
        IoError::BadHeader { .. }
    ));
    // complex samples
    let mut h = ok.clone();
    h[70..72].copy_from_slice(&32i16.to_le_bytes());
    h[72..74].copy_from_slice(&64i16.to_le_bytes());
    assert!(matches!(
        case("complex", [h, data.clone()].concat()),
        IoError::UnknownDType { .. }
    ));
    // vox_offset inside the header
    let mut h = ok.clone();
    h[108..112].copy_from_slice(&10f32.to_le_bytes());
    assert!(matches!(
        case("voxoff", [h, data.clone()].concat()),
        IoError::BadHeader { .. }
    ));
    // NaN voxel size
    let mut h = ok.clone();
    h[80..84].copy_from_slice(&f32::NAN.to_le_bytes());
    assert!(matches!(
        case("nanpix", [h, data.clone()].concat()),
        IoError::BadHeader { .. }
    ));
    // negative dim
    let mut h = ok.clone();
    h[44..46].copy_from_slice(&(-4i16).to_le_bytes());
    assert!(matches!(
        case("negdim", [h, data.clone()].concat()),
        IoError::BadHeader { .. }
    ));
    // a header cut short
    assert!(matches!(
        case("cut", ok[..200].to_vec()),
        IoError::Truncated { .. }
    ));
    // NaN samples in a float file
    let h = nifti_header(1, false, &[2, 1, 1], 16, 32, 0.0, 0.0, true);
    let nan: Vec<u8> = [1.0f32, f32::NAN]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    assert!(matches!(
        case("nan", [h, nan].concat()),
        IoError::Volume { .. }
    ));
}

// ---------------------------------------------------------------------------
// TIFF.

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn tiff_stack_fixture_decodes() {
    let Some(dir) = formats_dir() else { return };
    let t = truth("cells3d_nuclei_fluo");
    let p = dir.join("tiff/cells3d_nuclei.tif");
    let mut r = io::open(&p).unwrap();
    assert_eq!(r.format(), "TIFF");
    assert_eq!(r.desc().dims, t.desc.dims);
    assert_eq!(r.desc().dtype, t.desc.dtype);
    assert_same_voxels(&read_by_slabs(r.as_mut(), 7), &t, "tiff stack");
    // the file states no spacing: 1,1,1, or the caller's (the sidecar's)
    assert_eq!(r.desc().spacing, [1.0; 3]);
    let r = io::open_with(&p, &ReadOptions::default().spacing(Some(t.desc.spacing))).unwrap();
    assert_spacing(r.desc().spacing, t.desc.spacing, "tiff stack");
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn tiff_slice_folder_fixture_decodes() {
    let Some(dir) = formats_dir() else { return };
    let t = truth("cryoet_tomo");
    let p = dir.join("tiff_slices/cryoet_tomo");
    let mut r = io::open(&p).unwrap();
    assert_eq!(r.format(), "TIFF");
    assert_eq!(r.desc().dims, t.desc.dims);
    assert_eq!(r.desc().dtype, DType::F32);
    assert_spacing(r.desc().spacing, t.desc.spacing, "tiff slices");
    assert_eq!(r.input_files().len(), 101);
    assert_same_voxels(&read_by_slabs(r.as_mut(), 16), &t, "tiff slices");
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn tiff_slice_folder_with_unpadded_numbers() {
    let Some(dir) = formats_dir() else { return };
    let t = truth("cryoet_tomo");
    let src = dir.join("tiff_slices/cryoet_tomo");
    let d = TempDir::new().unwrap();
    // slice_0 ... slice_100: a plain sort would put slice_10 before slice_2;
    // written in a scrambled order so directory order says nothing either
    let mut ks: Vec<u32> = (0..101).collect();
    ks.sort_by_key(|k| (k * 37) % 101);
    for k in ks {
        std::fs::copy(
            src.join(format!("tomo_z{k:04}.tif")),
            d.path().join(format!("slice_{k}.tif")),
        )
        .unwrap();
    }
    let mut r = io::open(d.path()).unwrap();
    assert_same_voxels(&read_by_slabs(r.as_mut(), 101), &t, "unpadded slices");
    // a slice of another size in the folder: an error naming it
    let odd = d.path().join("slice_101.tif");
    std::fs::copy(dir.join("tiff/cells3d_nuclei.tif"), &odd).unwrap();
    let e = io::open(d.path()).err().expect("mixed sizes refused");
    assert!(
        matches!(&e, IoError::Inconsistent { file, .. } if file == &odd),
        "{e}"
    );
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn tiff_bad_files_are_typed_errors() {
    let Some(dir) = formats_dir() else { return };
    let d = TempDir::new().unwrap();
    let full = std::fs::read(dir.join("tiff/cells3d_nuclei.tif")).unwrap();
    for cut in [8usize, 1000, full.len() / 2, full.len() - 10] {
        let p = d.path().join(format!("cut{cut}.tif"));
        write(&p, &full[..cut]);
        let e = io::open(&p)
            .err()
            .unwrap_or_else(|| panic!("cut at {cut} opened"));
        assert!(e.to_string().contains(&p.display().to_string()), "{e}");
    }
}
