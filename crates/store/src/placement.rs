//! The placement record of format version 6: where the volume lies in the
//! world ([`Placement`]), after every other section of the file (see
//! `docs/store-format.md`).
//!
//! | offset | size | field |
//! |---:|---:|---|
//! | 0 | 96 | the affine's rows 0, 1, 2 (12 x f64, row by row) |
//! | 96 | 1 | space: 1 `RAS`, 2 `LPS`, 3 `image` |
//! | 97 | 3 | reserved, zero |
//! | 100 | 4 | CRC-32 of bytes 0..100 |
//!
//! The affine's last row is `0 0 0 1` and not stored.

use crate::error::StoreError;
use crate::format::PLACEMENT_LEN;
use brickray_io::Placement;
use std::path::Path;

/// The spaces a placement may name, by their code in the record.
const SPACES: [(u8, &str); 3] = [(1, "RAS"), (2, "LPS"), (3, "image")];

/// Where the record's CRC starts.
const CRC_AT: usize = PLACEMENT_LEN - 4;

fn bad(path: &Path, field: &'static str, reason: impl Into<String>) -> StoreError {
    StoreError::BadPlacement {
        path: path.to_owned(),
        field,
        reason: reason.into(),
    }
}

/// Checks that `affine` places a volume: every number finite, the last row
/// `0 0 0 1`, and the voxel axes spanning space (no zero column, a
/// determinant that is not zero relative to the columns' lengths).
fn check_affine(path: &Path, a: &[[f64; 4]; 4]) -> Result<(), StoreError> {
    if a.iter().flatten().any(|v| !v.is_finite()) {
        return Err(bad(path, "affine", format!("a non-finite number: {a:?}")));
    }
    if a[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(bad(
            path,
            "affine",
            format!("the last row is {:?}, not [0, 0, 0, 1]", a[3]),
        ));
    }
    let norms = [0, 1, 2].map(|c| a[..3].iter().map(|row| row[c] * row[c]).sum::<f64>().sqrt());
    if let Some(c) = norms.iter().position(|n| !(n.is_finite() && *n > 0.0)) {
        return Err(bad(
            path,
            "affine",
            format!("voxel axis {c} maps to no direction (a zero column)"),
        ));
    }
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    let scale: f64 = norms.iter().product();
    if !(det.is_finite() && det.abs() > 1e-12 * scale) {
        return Err(bad(
            path,
            "affine",
            format!("the voxel axes do not span space (determinant {det})"),
        ));
    }
    Ok(())
}

/// The record of `p`, or [`StoreError::BadPlacement`] (naming `path`, the
/// build's input) when it is not one the reader accepts: a non-finite or
/// singular affine, a last row other than `0 0 0 1`, a space other than
/// `RAS`, `LPS` and `image`.
pub(crate) fn encode(p: &Placement, path: &Path) -> Result<[u8; PLACEMENT_LEN], StoreError> {
    check_affine(path, &p.affine)?;
    let code = SPACES
        .iter()
        .find(|(_, s)| *s == p.space)
        .map(|(c, _)| *c)
        .ok_or_else(|| {
            bad(
                path,
                "space",
                format!("{:?} (must be RAS, LPS or image)", p.space),
            )
        })?;
    let mut b = [0u8; PLACEMENT_LEN];
    for (i, v) in p.affine[..3].iter().flatten().enumerate() {
        b[8 * i..8 * i + 8].copy_from_slice(&v.to_le_bytes());
    }
    b[96] = code;
    let crc = crc32fast::hash(&b[..CRC_AT]);
    b[CRC_AT..].copy_from_slice(&crc.to_le_bytes());
    Ok(b)
}

/// Reads and validates the record (`PLACEMENT_LEN` bytes, checked by the
/// caller; a shorter slice is [`StoreError::Truncated`]): its CRC
/// ([`StoreError::PlacementChecksum`]), then its fields
/// ([`StoreError::BadPlacement`]).
pub(crate) fn decode(b: &[u8], path: &Path) -> Result<Placement, StoreError> {
    let b: &[u8; PLACEMENT_LEN] = b.try_into().map_err(|_| StoreError::Truncated {
        path: path.to_owned(),
        section: "placement record",
        needed: PLACEMENT_LEN as u64,
        actual: b.len() as u64,
    })?;
    let stored = u32::from_le_bytes([b[CRC_AT], b[CRC_AT + 1], b[CRC_AT + 2], b[CRC_AT + 3]]);
    let computed = crc32fast::hash(&b[..CRC_AT]);
    if stored != computed {
        return Err(StoreError::PlacementChecksum {
            path: path.to_owned(),
            stored,
            computed,
        });
    }
    let f64_at = |o: usize| {
        let mut a = [0u8; 8];
        a.copy_from_slice(&b[o..o + 8]);
        f64::from_le_bytes(a)
    };
    let mut affine = [[0.0; 4]; 4];
    for (i, v) in affine[..3].iter_mut().flatten().enumerate() {
        *v = f64_at(8 * i);
    }
    affine[3] = [0.0, 0.0, 0.0, 1.0];
    let space = SPACES
        .iter()
        .find(|(c, _)| *c == b[96])
        .map(|(_, s)| *s)
        .ok_or_else(|| bad(path, "space", format!("unknown code {}", b[96])))?;
    if b[97..100] != [0; 3] {
        return Err(bad(path, "reserved", "non-zero"));
    }
    check_affine(path, &affine)?;
    Ok(Placement { affine, space })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lps() -> Placement {
        Placement {
            affine: [
                [0.0, -0.7, 0.0, 120.5],
                [-0.9, 0.0, 0.0, -3.25],
                [0.0, 0.0, 2.5, -0.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
            space: "LPS",
        }
    }

    #[test]
    fn round_trip_is_exact() {
        let p = Path::new("x");
        for space in ["RAS", "LPS", "image"] {
            let want = Placement { space, ..lps() };
            let got = decode(&encode(&want, p).unwrap(), p).unwrap();
            assert_eq!(got.space, space);
            let bits = |q: &Placement| q.affine.map(|r| r.map(f64::to_bits));
            assert_eq!(bits(&got), bits(&want));
        }
    }

    #[test]
    fn bad_placements_are_refused_on_both_sides() {
        let p = Path::new("x");
        let mut singular = lps();
        singular.affine[2] = [0.0, -1.4, 0.0, 0.0];
        let mut zero = lps();
        zero.affine[0][1] = 0.0;
        zero.affine[1][1] = 0.0;
        let mut nan = lps();
        nan.affine[1][3] = f64::NAN;
        let mut inf = lps();
        inf.affine[0][0] = f64::INFINITY;
        let mut row = lps();
        row.affine[3][0] = 1.0;
        for (q, field) in [
            (singular, "affine"),
            (zero, "affine"),
            (nan, "affine"),
            (inf, "affine"),
            (row, "affine"),
            (
                Placement {
                    space: "RAS+",
                    ..lps()
                },
                "space",
            ),
        ] {
            assert!(
                matches!(encode(&q, p), Err(StoreError::BadPlacement { field: f, .. }) if f == field),
                "{q:?}"
            );
        }
        // The same in a record whose CRC was recomputed.
        let good = encode(&lps(), p).unwrap();
        let reseal = |b: &mut [u8; PLACEMENT_LEN]| {
            let crc = crc32fast::hash(&b[..CRC_AT]);
            b[CRC_AT..].copy_from_slice(&crc.to_le_bytes());
        };
        for (o, bytes, field) in [
            (8, f64::NAN.to_le_bytes().to_vec(), "affine"),
            (80, f64::NEG_INFINITY.to_le_bytes().to_vec(), "affine"),
            (0, [0u8; 96].to_vec(), "affine"),
            (96, vec![0], "space"),
            (96, vec![4], "space"),
            (98, vec![1], "reserved"),
        ] {
            let mut b = good;
            b[o..o + bytes.len()].copy_from_slice(&bytes);
            reseal(&mut b);
            assert!(
                matches!(decode(&b, p), Err(StoreError::BadPlacement { field: f, .. }) if f == field),
                "offset {o}"
            );
        }
        let mut b = good;
        b[17] ^= 1;
        assert!(matches!(
            decode(&b, p),
            Err(StoreError::PlacementChecksum { .. })
        ));
        assert!(matches!(
            decode(&good[..50], p),
            Err(StoreError::Truncated { .. })
        ));
    }
}
