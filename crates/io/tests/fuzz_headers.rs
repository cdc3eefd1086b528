//! Header fuzzing: for each format, 10,000 deterministic mutations of a small
//! valid file's header (byte flips, boundary values, truncation) are opened
//! and, when they open, read whole. Every outcome must be a volume or a typed
//! error; a panic fails the test. The seed is fixed, so a failure reproduces.
#![cfg(all(
    feature = "nifti",
    feature = "tiff",
    feature = "dicom",
    feature = "zarr"
))]

use brickray_io as io;
use std::path::Path;
use tempfile::TempDir;

/// Mutations per format: 10,000, or `BRICKRAY_FUZZ_RUNS` (for a longer local run).
fn runs() -> usize {
    std::env::var("BRICKRAY_FUZZ_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000)
}

/// xorshift64*: deterministic, no dependency.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// One mutation of `base` within its first `header` bytes.
fn mutate(rng: &mut Rng, base: &[u8], header: usize) -> Vec<u8> {
    let mut b = base.to_vec();
    let h = header.min(b.len());
    for _ in 0..1 + rng.below(4) {
        let i = rng.below(h);
        match rng.below(6) {
            0 => b[i] ^= 1 << rng.below(8),
            1 => b[i] = [0x00, 0xff, 0x7f, 0x80, 0x01][rng.below(5)],
            2 => b[i] = rng.next() as u8,
            3 => {
                // a 4-byte boundary value (sizes, offsets, counts)
                let v: u32 = [0, 1, u32::MAX, 0x7fff_ffff, 0x8000_0000, 65536][rng.below(6)];
                let end = (i + 4).min(h);
                b[i..end].copy_from_slice(&v.to_le_bytes()[..end - i]);
            }
            4 => b[i] = b'0' + rng.below(10) as u8,
            _ => {
                if rng.below(4) == 0 {
                    b.truncate(rng.below(b.len()));
                    return b;
                }
            }
        }
    }
    b
}

/// Opens and reads; any `Err` is fine, a panic is not.
fn exercise(path: &Path) -> bool {
    match io::open(path) {
        Ok(mut r) => {
            let _ = r.read_volume();
            let d = r.desc().clone();
            // a slab read outside the volume is an error too
            let _ = r.read_slices(d.dims[2], d.dims[2] + 1, &mut []);
            true
        }
        Err(e) => {
            let _ = e.to_string();
            false
        }
    }
}

fn fuzz(name: &str, base: &[u8], header: usize, write: &dyn Fn(&[u8]) -> std::path::PathBuf) {
    assert!(
        exercise(&write(base)),
        "{name}: the unmutated input must open"
    );
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ name.len() as u64);
    let mut opened = 0;
    let t = std::time::Instant::now();
    for _ in 0..runs() {
        let m = mutate(&mut rng, base, header);
        if exercise(&write(&m)) {
            opened += 1;
        }
    }
    eprintln!(
        "{name}: {} mutated headers, {opened} opened, none panicked ({:.1} s)",
        runs(),
        t.elapsed().as_secs_f64()
    );
}

fn nifti_base() -> Vec<u8> {
    let mut b = vec![0u8; 352];
    b[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (i, d) in [3i16, 4, 3, 2].iter().enumerate() {
        b[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    b[70..72].copy_from_slice(&4i16.to_le_bytes());
    b[72..74].copy_from_slice(&16i16.to_le_bytes());
    for i in 0..4 {
        b[76 + 4 * i..80 + 4 * i].copy_from_slice(&1f32.to_le_bytes());
    }
    b[108..112].copy_from_slice(&352f32.to_le_bytes());
    b[252..254].copy_from_slice(&1i16.to_le_bytes());
    b[254..256].copy_from_slice(&1i16.to_le_bytes());
    b[280..284].copy_from_slice(&1f32.to_le_bytes());
    b[300..304].copy_from_slice(&1f32.to_le_bytes());
    b[320..324].copy_from_slice(&1f32.to_le_bytes());
    b[344..348].copy_from_slice(b"n+1\0");
    b.extend((0..24i16).flat_map(|v| (v * 100 - 1000).to_le_bytes()));
    b
}

#[test]
fn nifti_headers() {
    let d = TempDir::new().unwrap();
    let p = d.path().join("f.nii");
    fuzz("NIfTI", &nifti_base(), 352, &|b| {
        std::fs::write(&p, b).unwrap();
        p.clone()
    });
}

#[test]
fn nrrd_headers() {
    let d = TempDir::new().unwrap();
    let p = d.path().join("f.nrrd");
    let mut base = b"NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\nencoding: raw\nendian: little\nspacings: 1 1 2\n\n".to_vec();
    let h = base.len();
    base.extend((0..24i16).flat_map(|v| v.to_le_bytes()));
    fuzz("NRRD", &base, h, &|b| {
        std::fs::write(&p, b).unwrap();
        p.clone()
    });
}

#[test]
fn tiff_headers() {
    use tiff::encoder::{TiffEncoder, colortype};
    let mut cur = std::io::Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut cur).unwrap();
        for z in 0..3u16 {
            let page: Vec<u16> = (0..8 * 6).map(|i| i * 10 + z).collect();
            enc.write_image::<colortype::Gray16>(8, 6, &page).unwrap();
        }
    }
    let base = cur.into_inner();
    let d = TempDir::new().unwrap();
    let p = d.path().join("f.tif");
    // the whole file is header-like (IFDs follow the data): mutate all of it
    let n = base.len();
    fuzz("TIFF", &base, n, &|b| {
        std::fs::write(&p, b).unwrap();
        p.clone()
    });
}

#[test]
fn dicom_headers() {
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::tags;
    use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
    let mut obj = InMemDicomObject::new_empty();
    let put =
        |o: &mut InMemDicomObject, t, vr, v: PrimitiveValue| o.put(DataElement::new(t, vr, v));
    put(
        &mut obj,
        tags::SOP_CLASS_UID,
        VR::UI,
        "1.2.840.10008.5.1.4.1.1.2".into(),
    );
    put(&mut obj, tags::SOP_INSTANCE_UID, VR::UI, "1.2.3.4.1".into());
    put(
        &mut obj,
        tags::SERIES_INSTANCE_UID,
        VR::UI,
        "1.2.3.4".into(),
    );
    put(&mut obj, tags::MODALITY, VR::CS, "CT".into());
    put(
        &mut obj,
        tags::IMAGE_POSITION_PATIENT,
        VR::DS,
        PrimitiveValue::from("0\\0\\0"),
    );
    put(
        &mut obj,
        tags::IMAGE_ORIENTATION_PATIENT,
        VR::DS,
        PrimitiveValue::from("1\\0\\0\\0\\1\\0"),
    );
    put(
        &mut obj,
        tags::PIXEL_SPACING,
        VR::DS,
        PrimitiveValue::from("0.5\\0.5"),
    );
    put(
        &mut obj,
        tags::SAMPLES_PER_PIXEL,
        VR::US,
        PrimitiveValue::from(1u16),
    );
    put(
        &mut obj,
        tags::PHOTOMETRIC_INTERPRETATION,
        VR::CS,
        "MONOCHROME2".into(),
    );
    put(&mut obj, tags::ROWS, VR::US, PrimitiveValue::from(6u16));
    put(&mut obj, tags::COLUMNS, VR::US, PrimitiveValue::from(8u16));
    put(
        &mut obj,
        tags::BITS_ALLOCATED,
        VR::US,
        PrimitiveValue::from(16u16),
    );
    put(
        &mut obj,
        tags::BITS_STORED,
        VR::US,
        PrimitiveValue::from(12u16),
    );
    put(
        &mut obj,
        tags::HIGH_BIT,
        VR::US,
        PrimitiveValue::from(11u16),
    );
    put(
        &mut obj,
        tags::PIXEL_REPRESENTATION,
        VR::US,
        PrimitiveValue::from(0u16),
    );
    put(&mut obj, tags::RESCALE_INTERCEPT, VR::DS, "-1024".into());
    put(&mut obj, tags::RESCALE_SLOPE, VR::DS, "1".into());
    let px: Vec<u16> = (0..48).map(|i| i * 50).collect();
    put(
        &mut obj,
        tags::PIXEL_DATA,
        VR::OW,
        PrimitiveValue::U16(px.into()),
    );
    let file = obj
        .with_meta(
            FileMetaTableBuilder::new()
                .transfer_syntax("1.2.840.10008.1.2.1")
                .media_storage_sop_class_uid("1.2.840.10008.5.1.4.1.1.2")
                .media_storage_sop_instance_uid("1.2.3.4.1"),
        )
        .unwrap();
    let d = TempDir::new().unwrap();
    let p = d.path().join("s.dcm");
    file.write_to_file(&p).unwrap();
    let base = std::fs::read(&p).unwrap();
    let n = base.len() - 96;
    fuzz("DICOM", &base, n, &|b| {
        std::fs::write(&p, b).unwrap();
        d.path().to_owned()
    });
}

#[test]
fn ome_zarr_metadata() {
    let d = TempDir::new().unwrap();
    let root = d.path().join("f.ome.zarr");
    std::fs::create_dir_all(root.join("s0/c/0/0")).unwrap();
    let group = br#"{"zarr_format":3,"node_type":"group","attributes":{"ome":{"version":"0.5","multiscales":[{"axes":[{"name":"z","type":"space"},{"name":"y","type":"space"},{"name":"x","type":"space"}],"datasets":[{"path":"s0","coordinateTransformations":[{"type":"scale","scale":[2.0,1.0,1.0]}]}]}]}}}"#;
    let array = br#"{"zarr_format":3,"node_type":"array","shape":[2,3,4],"data_type":"uint16","chunk_grid":{"name":"regular","configuration":{"chunk_shape":[2,3,4]}},"chunk_key_encoding":{"name":"default","configuration":{"separator":"/"}},"fill_value":0,"codecs":[{"name":"bytes","configuration":{"endian":"little"}}]}"#;
    let chunk: Vec<u8> = (0..24u16).flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(root.join("s0/c/0/0/0"), &chunk).unwrap();
    std::fs::write(root.join("s0/zarr.json"), array).unwrap();
    let g = root.join("zarr.json");
    fuzz("OME-Zarr group", group, group.len(), &|b| {
        std::fs::write(&g, b).unwrap();
        root.clone()
    });
    std::fs::write(&g, group).unwrap();
    let a = root.join("s0/zarr.json");
    fuzz("OME-Zarr array", array, array.len(), &|b| {
        std::fs::write(&a, b).unwrap();
        root.clone()
    });
}
