//! Raw + JSON and NRRD under a mutation fuzz (proptest): mutated headers and
//! data never panic and never allocate absurdly. The typed errors for each
//! kind of bad input are in `io_bad_input.rs`; the other formats' header fuzz
//! in `fuzz_headers.rs`.

mod common;

use brickray_core::DType;
use brickray_io as io;
use common::*;
use std::path::Path;
use tempfile::TempDir;

// ---------------------------------------------------------------------------
// Fuzz: mutated headers and data never panic and never allocate absurdly.

mod fuzz {
    use super::*;
    use proptest::prelude::*;

    #[derive(Debug, Clone)]
    enum Mutation {
        Flip(usize, u8),
        Truncate(usize),
        InsertLine(usize, String),
        Replace(usize, u8),
    }

    fn mutation() -> impl Strategy<Value = Mutation> {
        prop_oneof![
            (any::<usize>(), 0u8..8).prop_map(|(i, b)| Mutation::Flip(i, b)),
            any::<usize>().prop_map(Mutation::Truncate),
            (
                any::<usize>(),
                prop_oneof![
                    Just("sizes: 100000 100000 100000".to_owned()),
                    Just("sizes: 65536 65536 1".to_owned()),
                    Just("dimension: 4".to_owned()),
                    Just("type: double".to_owned()),
                    Just("encoding: gzip".to_owned()),
                    Just("endian: big".to_owned()),
                    Just("spacings: nan nan nan".to_owned()),
                    Just("space directions: (0,0,0) (1,1,1) none".to_owned()),
                    Just("data file: /nonexistent".to_owned()),
                    Just("\"dims\": [4294967295, 4294967295, 4294967295],".to_owned()),
                    Just("\"dims\": [65536, 65536, 1],".to_owned()),
                    "[ -~]{0,40}",
                ]
            )
                .prop_map(|(i, s)| Mutation::InsertLine(i, s)),
            (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Mutation::Replace(i, b)),
        ]
    }

    fn apply(mut b: Vec<u8>, muts: &[Mutation]) -> Vec<u8> {
        for m in muts {
            if b.is_empty() {
                break;
            }
            match m {
                Mutation::Flip(i, bit) => {
                    let n = b.len();
                    b[i % n] ^= 1 << bit;
                }
                Mutation::Truncate(i) => {
                    let n = b.len();
                    b.truncate(i % n);
                }
                Mutation::InsertLine(i, s) => {
                    // at a line start
                    let n = b.len();
                    let mut at = i % n;
                    while at > 0 && b[at - 1] != b'\n' {
                        at -= 1;
                    }
                    let line = format!("{s}\n");
                    b.splice(at..at, line.into_bytes());
                }
                Mutation::Replace(i, v) => {
                    let n = b.len();
                    b[i % n] = *v;
                }
            }
        }
        b
    }

    fn check(path: &Path) {
        // Either outcome is fine; a panic or an abort on allocation fails the test.
        if let Ok(v) = io::read_volume(path) {
            let desc = v.desc();
            assert!(desc.byte_len() <= 1 << 20, "{desc:?}");
            assert!(desc.spacing.iter().all(|s| s.is_finite() && *s > 0.0));
            assert!(desc.value_range[0] < desc.value_range[1]);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 160, failure_persistence: None, ..ProptestConfig::default() })]

        #[test]
        fn mutated_nrrd_never_panics(muts in proptest::collection::vec(mutation(), 1..4), gz in any::<bool>(), f32s in any::<bool>()) {
            let dir = TempDir::new().unwrap();
            let dtype = if f32s { DType::F32 } else { DType::I16 };
            let (le, _) = samples(dtype, [5, 4, 3], 11);
            let payload = if gz { gzip(&le) } else { le.clone() };
            let fields = format!("{}min: -10\nmax: 10\n", nrrd_fields(dtype, [5, 4, 3], if gz { "gzip" } else { "raw" }, false));
            let mut b = format!("NRRD0004\n{fields}\n").into_bytes();
            b.extend_from_slice(&payload);
            let p = write(&dir.path().join("f.nrrd"), &apply(b, &muts));
            check(&p);
            // the same mutations on a detached header
            let h = format!("NRRD0004\n{fields}data file: f.data\n").into_bytes();
            write(&dir.path().join("f.data"), &payload);
            let p = write(&dir.path().join("f.nhdr"), &apply(h, &muts));
            check(&p);
        }

        #[test]
        fn mutated_sidecar_never_panics(muts in proptest::collection::vec(mutation(), 1..4)) {
            let dir = TempDir::new().unwrap();
            let (le, _) = samples(DType::U16, [5, 4, 3], 12);
            write(&dir.path().join("s.raw"), &le);
            let j = serde_json::to_string_pretty(&serde_json::json!({
                "dims": [5, 4, 3], "dtype": "u16", "spacing": [1.0, 2.0, 0.5],
                "file": "s.raw", "byte_order": "little", "value_range": [0.0, 65535.0]
            })).unwrap();
            let p = write(&dir.path().join("s.json"), &apply(j.into_bytes(), &muts));
            check(&p);
        }
    }
}
