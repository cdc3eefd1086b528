//! Placement of NRRD (`space`, `space directions`, `space origin`) and raw +
//! JSON sidecar (`affine`, `affine_space`) volumes: what each reports, and the
//! typed errors of malformed values.

mod common;

use brickray_core::DType;
use brickray_io::{self as io, IoError, Placement, VolumeReader};
use common::*;
use proptest::prelude::*;
use std::path::Path;
use tempfile::TempDir;

const BASE: &str = "type: short\ndimension: 3\nsizes: 7 5 3\nencoding: raw\nendian: little\n";

fn open_nrrd(dir: &Path, name: &str, fields: &str) -> Box<dyn VolumeReader> {
    let (le, _) = samples(DType::I16, DIMS, 3);
    let p = write_attached(dir, name, &format!("{BASE}{fields}"), &le);
    io::open(&p).unwrap_or_else(|e| panic!("{fields}: {e}"))
}

fn nrrd_error(dir: &Path, fields: &str) -> IoError {
    let (le, _) = samples(DType::I16, DIMS, 3);
    match io::open(write_attached(dir, "bad", &format!("{BASE}{fields}"), &le)) {
        Ok(r) => panic!("{fields}: expected an error, read {:?}", r.desc()),
        Err(e) => e,
    }
}

fn assert_affine_near(got: &[[f64; 4]; 4], want: &[[f64; 4]; 4], tol: f64, what: &str) {
    for r in 0..4 {
        for c in 0..4 {
            assert!(
                (got[r][c] - want[r][c]).abs() <= tol,
                "{what}: affine[{r}][{c}] = {}, want {} ({got:?})",
                got[r][c],
                want[r][c]
            );
        }
    }
}

// ---------------------------------------------------------------------------
// NRRD.

#[test]
fn nrrd_lps_rotated_flipped_anisotropic_gives_that_affine() {
    let dir = TempDir::new().unwrap();
    // i: 0.5 along a 30-degree rotation in the x-y plane (cos 0.8, sin 0.6);
    // j: 1.25, perpendicular to it and mirrored; k: 3 along -z (a flip).
    let fields = "space: left-posterior-superior\n\
                  space directions: (0.4,0.3,0) (0.75,-1,0) (0,0,-3)\n\
                  space origin: (-12.5,100.25,7)\n";
    let r = open_nrrd(dir.path(), "lps", fields);
    let pl = r.placement().expect("a placement");
    assert_eq!(pl.space, "LPS");
    let want = [
        [0.4, 0.75, 0.0, -12.5],
        [0.3, -1.0, 0.0, 100.25],
        [0.0, 0.0, -3.0, 7.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    assert_eq!(pl.affine, want);
    // spacing: the vectors' lengths
    assert_eq!(r.desc().spacing, [0.5, 1.25, 3.0]);
    assert!(r.warnings().is_empty(), "{:?}", r.warnings());
    // voxel centres where the affine says
    let w = pl.voxel_to_world([1.0, 1.0, 1.0]);
    for (a, b) in w.iter().zip([-11.35, 99.55, 4.0]) {
        assert!((a - b).abs() < 1e-12, "{w:?}");
    }
    // the abbreviation and any case name the same space
    let r = open_nrrd(
        dir.path(),
        "lps2",
        &fields.replace("left-posterior-superior", "LPS"),
    );
    assert_eq!(r.placement(), Some(pl));
    let r = open_nrrd(
        dir.path(),
        "lps3",
        &fields.replace("left-posterior-superior", "Left-Posterior-Superior"),
    );
    assert_eq!(r.placement(), Some(pl));
    // detached headers and gzip read the same fields
    let (le, _) = samples(DType::I16, DIMS, 3);
    let p = write_detached(dir.path(), "det", &format!("{BASE}{fields}"), &le);
    assert_eq!(io::open(&p).unwrap().placement(), Some(pl));
}

#[test]
fn nrrd_ras_las_and_non_anatomical_spaces_map_right() {
    let dir = TempDir::new().unwrap();
    let dirs = "space directions: (0,1.5,0) (-2,0,0) (0,0,0.5)\nspace origin: (10,-20,30)\n";
    let ras = [
        [0.0, -2.0, 0.0, 10.0],
        [1.5, 0.0, 0.0, -20.0],
        [0.0, 0.0, 0.5, 30.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    // LAS is RAS with x negated: row 0 flips
    let mut las = ras;
    las[0] = [-0.0, 2.0, -0.0, -10.0];
    for (space, want_space, want) in [
        ("right-anterior-superior", "RAS", ras),
        ("RAS", "RAS", ras),
        ("left-anterior-superior", "RAS", las),
        ("LAS", "RAS", las),
        ("scanner-xyz", "image", ras),
        ("3D-right-handed", "image", ras),
        ("3D-left-handed", "image", ras),
    ] {
        let r = open_nrrd(dir.path(), "sp", &format!("space: {space}\n{dirs}"));
        let pl = r.placement().expect(space);
        assert_eq!(pl.space, want_space, "{space}");
        assert_eq!(pl.affine, want, "{space}");
        assert_eq!(r.desc().spacing, [1.5, 2.0, 0.5], "{space}");
        assert!(r.warnings().is_empty(), "{space}: {:?}", r.warnings());
    }
    // LAS's world position of a voxel is the RAS one with x negated
    let r = open_nrrd(dir.path(), "las", &format!("space: LAS\n{dirs}"));
    let w = r.placement().unwrap().voxel_to_world([2.0, 1.0, 4.0]);
    for (a, b) in w.iter().zip([-(10.0 - 2.0), -20.0 + 3.0, 30.0 + 2.0]) {
        assert!((a - b).abs() < 1e-12, "{w:?}");
    }
    // an unnamed 3D space: image
    let r = open_nrrd(dir.path(), "sd", &format!("space dimension: 3\n{dirs}"));
    let pl = r.placement().unwrap();
    assert_eq!((pl.space, pl.affine), ("image", ras));
}

#[test]
fn nrrd_without_space_fields_keeps_spacings_and_no_placement() {
    let dir = TempDir::new().unwrap();
    // spacings only: as before, no placement
    let r = open_nrrd(dir.path(), "sp", "spacings: 0.5 1.25 3\n");
    assert_eq!(r.placement(), None);
    assert_eq!(r.desc().spacing, SPACING);
    assert!(r.warnings().is_empty());
    // nothing: isotropic 1, no placement
    let r = open_nrrd(dir.path(), "none", "");
    assert_eq!(r.placement(), None);
    assert_eq!(r.desc().spacing, [1.0; 3]);
    // a space and an origin without directions: no placement either
    let r = open_nrrd(
        dir.path(),
        "orig",
        "space: RAS\nspace origin: (1,2,3)\nspacings: 0.5 1.25 3\n",
    );
    assert_eq!(r.placement(), None);
    assert_eq!(r.desc().spacing, SPACING);
}

#[test]
fn nrrd_missing_space_or_origin_is_placed_with_a_warning() {
    let dir = TempDir::new().unwrap();
    let r = open_nrrd(
        dir.path(),
        "noorigin",
        "space: RAS\nspace directions: (0.5,0,0) (0,1.25,0) (0,0,3)\n",
    );
    let pl = r.placement().unwrap();
    assert_eq!(
        pl,
        Placement::axis_aligned([0.5, 1.25, 3.0], [0.0; 3], "RAS")
    );
    assert!(
        r.warnings().iter().any(|w| w.contains("space origin")),
        "{:?}",
        r.warnings()
    );
    let r = open_nrrd(
        dir.path(),
        "nospace",
        "space directions: (0.5,0,0) (0,1.25,0) (0,0,3)\nspace origin: (1,2,3)\n",
    );
    let pl = r.placement().unwrap();
    assert_eq!(
        pl,
        Placement::axis_aligned([0.5, 1.25, 3.0], [1.0, 2.0, 3.0], "image")
    );
    assert!(
        r.warnings().iter().any(|w| w.contains("image space")),
        "{:?}",
        r.warnings()
    );
    // 4D with a leading non-spatial axis: its "none" is dropped
    let (le, _) = samples(DType::I16, DIMS, 3);
    let f = "type: short\ndimension: 4\nsizes: 1 7 5 3\nencoding: raw\nendian: little\n\
             space: LPS\nspace directions: none (0,0.5,0) (1.25,0,0) (0,0,3)\n\
             space origin: (4,5,6)\nspacings: nan nan nan nan\n";
    let r = io::open(write_attached(dir.path(), "four", f, &le)).unwrap();
    let pl = r.placement().unwrap();
    assert_eq!(pl.space, "LPS");
    assert_eq!(
        pl.affine,
        [
            [0.0, 1.25, 0.0, 4.0],
            [0.5, 0.0, 0.0, 5.0],
            [0.0, 0.0, 3.0, 6.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    );
    assert_eq!(r.desc().spacing, SPACING);
}

#[test]
fn nrrd_malformed_space_fields_are_typed_errors() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let dirs = "space directions: (1,0,0) (0,1,0) (0,0,1)\n";
    // unparsable, wrong counts, none on a spatial axis, a bad space dimension
    for f in [
        "space directions: (1,0,0 (0,1,0) (0,0,1)\n".to_owned(),
        "space directions: (1,0,0) (0,1,0) (0,0,1\n".to_owned(),
        "space directions: 1,0,0 0,1,0 0,0,1\n".to_owned(),
        "space directions: (1,0,0) (0,1,0) (0,0,1) junk\n".to_owned(),
        "space directions: (1;0;0) (0,1,0) (0,0,1)\n".to_owned(),
        "space directions: (1,0,0) (0,1,0) (0,0,1) (1,1,1)\n".to_owned(),
        "space directions: (1,0,0,0) (0,1,0,0) (0,0,1,0)\n".to_owned(),
        "space directions: (1,0,0) none (0,0,1)\n".to_owned(),
        "space directions: (1,0,0) nonesuch (0,0,1)\n".to_owned(),
        "space directions: \n".to_owned(),
        format!("{dirs}space origin: (1,2)\n"),
        format!("{dirs}space origin: (1,2,3) (4,5,6)\n"),
        format!("{dirs}space origin: none\n"),
        format!("{dirs}space origin: (1,2,3\n"),
        format!("{dirs}space origin: 1 2 3\n"),
        format!("space: RAS\nspace dimension: 2\n{dirs}"),
        format!("space dimension: three\n{dirs}"),
        format!("space: right-posterior-inferior\n{dirs}"),
        // spacings and directions disagreeing on an axis
        format!("{dirs}spacings: 1 2 1\n"),
    ] {
        let e = nrrd_error(d, &f);
        assert!(matches!(e, IoError::BadHeader { .. }), "{f}: {e}");
    }
    // NaN and infinity
    for (f, field) in [
        (
            "space directions: (nan,0,0) (0,1,0) (0,0,1)\n",
            "space directions",
        ),
        (
            "space directions: (1,0,0) (0,inf,0) (0,0,1)\n",
            "space directions",
        ),
        (
            "space directions: (1,0,0) (0,1,0) (0,0,-1e999)\n",
            "space directions",
        ),
        (
            "space directions: (1,0,0) (0,1,0) (0,0,1)\nspace origin: (0,NaN,0)\n",
            "space origin",
        ),
    ] {
        let e = nrrd_error(d, f);
        assert!(
            matches!(&e, IoError::NonFiniteValue { field: got, .. } if *got == field),
            "{f}: {e}"
        );
    }
    // singular: coplanar, parallel, almost parallel directions
    for f in [
        "space directions: (1,0,0) (0,1,0) (1,1,0)\n",
        "space directions: (1,0,0) (2,0,0) (0,0,1)\n",
        "space directions: (1,0,0) (1,1e-12,0) (0,0,1)\n",
    ] {
        let e = nrrd_error(d, f);
        assert!(
            matches!(&e, IoError::BadHeader { msg, .. } if msg.contains("span")),
            "{f}: {e}"
        );
    }
    // world spaces with time, other space dimensions: unsupported
    for f in [
        "space: right-anterior-superior-time\nspace directions: (1,0,0,0) (0,1,0,0) (0,0,1,0)\n",
        "space: LPST\n",
        "space dimension: 4\n",
        "space dimension: 2\n",
    ] {
        let e = nrrd_error(d, f);
        assert!(matches!(e, IoError::Unsupported { .. }), "{f}: {e}");
    }
    // 4D whose leading axis has a direction
    let (le, _) = samples(DType::I16, DIMS, 3);
    let f = "type: short\ndimension: 4\nsizes: 1 7 5 3\nencoding: raw\nendian: little\n\
             space directions: (1,0,0) (1,0,0) (0,1,0) (0,0,1)\n";
    let e = err_of(&write_attached(d, "four", f, &le));
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
    // spacings that agree with the directions, or are NaN, are accepted
    for sp in ["spacings: 1 1 1\n", "spacings: nan nan nan\n"] {
        let r = open_nrrd(d, "agree", &format!("space: RAS\n{dirs}{sp}"));
        assert_eq!(r.desc().spacing, [1.0; 3]);
        assert!(r.placement().is_some());
    }
}

/// A rotation from a (not necessarily unit) quaternion.
fn rotation(q: [f64; 4]) -> [[f64; 3]; 3] {
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    let [a, b, c, d] = q.map(|x| x / n);
    [
        [
            a * a + b * b - c * c - d * d,
            2.0 * (b * c - a * d),
            2.0 * (b * d + a * c),
        ],
        [
            2.0 * (b * c + a * d),
            a * a - b * b + c * c - d * d,
            2.0 * (c * d - a * b),
        ],
        [
            2.0 * (b * d - a * c),
            2.0 * (c * d + a * b),
            a * a - b * b - c * c + d * d,
        ],
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Random rotations, flips, spacings and origins written to an NRRD
    /// header read back as that affine (within 1e-9), in the named space.
    #[test]
    fn nrrd_random_orientations_read_back(
        q in prop::array::uniform4(-1.0f64..1.0).prop_filter("non-zero", |q| {
            q.iter().map(|x| x * x).sum::<f64>() > 1e-3
        }),
        flips in prop::array::uniform3(any::<bool>()),
        spacing in prop::array::uniform3(0.01f64..10.0),
        origin in prop::array::uniform3(-500.0f64..500.0),
        space in 0usize..4,
    ) {
        let (name, want_space, sign) = [
            ("LPS", "LPS", [1.0, 1.0, 1.0]),
            ("right-anterior-superior", "RAS", [1.0, 1.0, 1.0]),
            ("left-anterior-superior", "RAS", [-1.0, 1.0, 1.0]),
            ("scanner-xyz", "image", [1.0, 1.0, 1.0]),
        ][space];
        let r = rotation(q);
        // column c: axis c's direction
        let cols: Vec<[f64; 3]> = (0..3)
            .map(|c| {
                let s = if flips[c] { -spacing[c] } else { spacing[c] };
                [r[0][c] * s, r[1][c] * s, r[2][c] * s]
            })
            .collect();
        let v = |x: [f64; 3]| format!("({:?},{:?},{:?})", x[0], x[1], x[2]);
        let fields = format!(
            "space: {name}\nspace directions: {} {} {}\nspace origin: {}\n",
            v(cols[0]), v(cols[1]), v(cols[2]), v(origin)
        );
        let dir = TempDir::new().unwrap();
        let rd = open_nrrd(dir.path(), "p", &fields);
        let pl = rd.placement().unwrap();
        prop_assert_eq!(pl.space, want_space);
        let mut want = [[0.0; 4]; 4];
        for row in 0..3 {
            for (c, col) in cols.iter().enumerate() {
                want[row][c] = sign[row] * col[row];
            }
            want[row][3] = sign[row] * origin[row];
        }
        want[3][3] = 1.0;
        assert_affine_near(&pl.affine, &want, 1e-9, &fields);
        for (&got, want) in rd.desc().spacing.iter().zip(spacing) {
            let got = f64::from(got);
            prop_assert!((got - want).abs() <= 1e-6 * want, "{:?}", rd.desc().spacing);
        }
        prop_assert!(rd.warnings().is_empty());
    }
}

// ---------------------------------------------------------------------------
// Raw + JSON sidecar.

fn sidecar_with(affine: serde_json::Value, space: serde_json::Value) -> serde_json::Value {
    let mut j = sidecar_json("u8", DIMS.map(u64::from), SPACING);
    j["affine"] = affine;
    j["affine_space"] = space;
    j
}

fn open_sidecar(
    dir: &Path,
    name: &str,
    j: serde_json::Value,
) -> Result<Box<dyn VolumeReader>, IoError> {
    let (le, _) = samples(DType::U8, DIMS, 5);
    io::open(write_sidecar(dir, name, j, &le))
}

#[test]
fn raw_sidecar_placement_round_trip() {
    let dir = TempDir::new().unwrap();
    let (le, values) = samples(DType::U8, DIMS, 5);
    // what `brickray-store convert` writes: the placement as serde_json gives it
    let pl = Placement {
        affine: [
            [0.0, -1.25, 0.0, 17.5],
            [-0.5, 0.0, 0.0, 0.1],
            [0.0, 0.0, 3.0, -42.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
        space: "LPS",
    };
    for space in ["RAS", "LPS", "image"] {
        let pl = Placement { space, ..pl };
        let j = sidecar_with(serde_json::json!(pl.affine), serde_json::json!(pl.space));
        let p = write_sidecar(dir.path(), space, j, &le);
        let mut r = io::open(&p).unwrap();
        assert_eq!(r.placement(), Some(pl));
        assert!(r.notes().is_empty(), "{:?}", r.notes());
        // the rest as without the keys
        let vol = r.read_volume().unwrap();
        check_volume(&vol, DType::U8, DIMS, SPACING, &le, &values);
    }
    // 3 rows: the 4th is implied
    let j = sidecar_with(serde_json::json!(&pl.affine[..3]), serde_json::json!("LPS"));
    assert_eq!(
        open_sidecar(dir.path(), "three", j).unwrap().placement(),
        Some(pl)
    );
    // an NRRD's placement, written as convert writes it, reads back equal
    let nrrd = open_nrrd(
        dir.path(),
        "src",
        "space: LAS\nspace directions: (0.1,0.2,0.3) (0,-1.5,0.7) (2,0,-0.25)\nspace origin: (1e-3,-7,12345.678)\n",
    );
    let src = nrrd.placement().unwrap();
    let j = sidecar_with(serde_json::json!(src.affine), serde_json::json!(src.space));
    assert_eq!(
        open_sidecar(dir.path(), "fromnrrd", j).unwrap().placement(),
        Some(src)
    );
}

#[test]
fn raw_sidecar_without_placement_keys_is_unchanged() {
    let dir = TempDir::new().unwrap();
    let r = open_sidecar(
        dir.path(),
        "plain",
        sidecar_json("u8", DIMS.map(u64::from), SPACING),
    )
    .unwrap();
    assert_eq!(r.placement(), None);
    assert!(r.notes().is_empty());
    assert!(r.warnings().is_empty());
    // an affine without its space (older sidecars copied a NIfTI's so): not
    // used, and said in the notes
    let mut j = sidecar_json("u8", DIMS.map(u64::from), SPACING);
    j["affine"] = serde_json::json!([
        [-1, 0, 0, 125.8],
        [0, 0, 1, -94.5],
        [0, -1, 0, 133.3],
        [0, 0, 0, 1]
    ]);
    let r = open_sidecar(dir.path(), "nospace", j).unwrap();
    assert_eq!(r.placement(), None);
    assert!(
        r.notes().iter().any(|n| n.contains("affine_space")),
        "{:?}",
        r.notes()
    );
    assert!(r.warnings().is_empty());
    assert_eq!(r.desc().spacing, SPACING);
}

#[test]
fn raw_sidecar_bad_placement_is_a_typed_error() {
    let dir = TempDir::new().unwrap();
    let id = serde_json::json!([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]);
    for (what, affine, space) in [
        (
            "2 rows",
            serde_json::json!([[1, 0, 0, 0], [0, 1, 0, 0]]),
            "RAS",
        ),
        (
            "5 rows",
            serde_json::json!([
                [1, 0, 0, 0],
                [0, 1, 0, 0],
                [0, 0, 1, 0],
                [0, 0, 0, 1],
                [0, 0, 0, 1]
            ]),
            "RAS",
        ),
        (
            "short row",
            serde_json::json!([[1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]),
            "RAS",
        ),
        (
            "long row",
            serde_json::json!([[1, 0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]),
            "RAS",
        ),
        (
            "flat",
            serde_json::json!([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]),
            "RAS",
        ),
        (
            "string",
            serde_json::json!([[1, 0, 0, 0], [0, "1", 0, 0], [0, 0, 1, 0]]),
            "RAS",
        ),
        (
            "null entry",
            serde_json::json!([[1, 0, 0, 0], [0, null, 0, 0], [0, 0, 1, 0]]),
            "RAS",
        ),
        ("not an array", serde_json::json!("identity"), "RAS"),
        (
            "last row",
            serde_json::json!([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]),
            "RAS",
        ),
        (
            "projective",
            serde_json::json!([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 2]]),
            "RAS",
        ),
        (
            "zero column",
            serde_json::json!([[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0]]),
            "RAS",
        ),
        (
            "coplanar",
            serde_json::json!([[1, 0, 1, 0], [0, 1, 1, 0], [0, 0, 0, 0]]),
            "LPS",
        ),
        ("unknown space", id.clone(), "LAS"),
        ("empty space", id.clone(), ""),
    ] {
        let e = open_sidecar(
            dir.path(),
            "bad",
            sidecar_with(affine, serde_json::json!(space)),
        )
        .err()
        .unwrap_or_else(|| panic!("{what}: expected an error"));
        assert!(matches!(e, IoError::BadHeader { .. }), "{what}: {e}");
    }
    // a space that is not a string, a space without an affine
    let e = open_sidecar(dir.path(), "bad", sidecar_with(id, serde_json::json!(3)))
        .err()
        .unwrap();
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
    let mut j = sidecar_json("u8", DIMS.map(u64::from), SPACING);
    j["affine_space"] = serde_json::json!("RAS");
    let e = open_sidecar(dir.path(), "bad", j).err().unwrap();
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
    // a number beyond f64 (JSON has no NaN): refused by the JSON parser, typed
    let (le, _) = samples(DType::U8, DIMS, 5);
    let text = r#"{"dims":[7,5,3],"dtype":"u8","affine":[[1e999,0,0,0],[0,1,0,0],[0,0,1,0]],"affine_space":"RAS"}"#;
    write(&dir.path().join("huge.raw"), &le);
    let e = err_of(&write(&dir.path().join("huge.json"), text.as_bytes()));
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Any non-singular affine and space a sidecar states reads back equal.
    #[test]
    fn raw_sidecar_random_placements_read_back_equal(
        q in prop::array::uniform4(-1.0f64..1.0).prop_filter("non-zero", |q| {
            q.iter().map(|x| x * x).sum::<f64>() > 1e-3
        }),
        scale in prop::array::uniform3(prop_oneof![-10.0f64..-0.01, 0.01f64..10.0]),
        origin in prop::array::uniform3(-1e4f64..1e4),
        space in prop::sample::select(vec!["RAS", "LPS", "image"]),
        three_rows in any::<bool>(),
    ) {
        let r = rotation(q);
        let mut affine = [[0.0; 4]; 4];
        for row in 0..3 {
            for c in 0..3 {
                affine[row][c] = r[row][c] * scale[c];
            }
            affine[row][3] = origin[row];
        }
        affine[3][3] = 1.0;
        let pl = Placement { affine, space };
        let rows = if three_rows { &affine[..3] } else { &affine[..] };
        let dir = TempDir::new().unwrap();
        let rd = open_sidecar(
            dir.path(),
            "p",
            sidecar_with(serde_json::json!(rows), serde_json::json!(space)),
        ).unwrap();
        prop_assert_eq!(rd.placement(), Some(pl));
    }
}

// ---------------------------------------------------------------------------
// The shared data sets' sidecars open as before: no placement (one has an
// affine without a space, which is noted, not used).

#[test]
fn shared_sidecars_have_no_placement() {
    let Some(root) = shared_data_root() else {
        return;
    };
    let mut seen = 0;
    for top in [root.clone(), root.join("labels")] {
        for dir in std::fs::read_dir(&top).unwrap().map(|e| e.unwrap().path()) {
            let Some(name) = dir.file_name().and_then(|n| n.to_str()) else {
                continue;
            };
            let json = dir.join(format!("{name}.json"));
            if !json.is_file() {
                continue;
            }
            let sc: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
            let r = io::open(&json).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(r.warnings().is_empty(), "{name}: {:?}", r.warnings());
            if sc.get("affine_space").is_none() {
                assert_eq!(r.placement(), None, "{name}");
                assert_eq!(
                    r.notes().is_empty(),
                    sc.get("affine").is_none(),
                    "{name}: {:?}",
                    r.notes()
                );
            }
            seen += 1;
        }
    }
    assert!(seen >= 5, "expected the shared sidecars, found {seen}");
}
