use super::*;
use parking_lot::Mutex;
use proptest::prelude::*;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};

/// Objects in memory; counts the reads that reach the "network".
#[derive(Debug, Default)]
struct Fake {
    objects: Mutex<HashMap<String, Vec<u8>>>,
    reads: AtomicU64,
}

impl Fake {
    fn with(objects: &[(&str, Vec<u8>)]) -> Fake {
        let f = Fake::default();
        for (k, v) in objects {
            f.objects.lock().insert(k.to_string(), v.clone());
        }
        f
    }
    fn reads(&self) -> u64 {
        self.reads.load(Ordering::Relaxed)
    }
}

impl ObjectReader for Fake {
    fn location(&self) -> &str {
        "mem://image.zarr"
    }
    fn read_object(&self, key: &str, span: ObjectSpan) -> io::Result<Option<(Vec<u8>, u64)>> {
        self.reads.fetch_add(1, Ordering::Relaxed);
        let objects = self.objects.lock();
        let Some(v) = objects.get(key) else {
            return Ok(None);
        };
        let n = v.len() as u64;
        let (a, b) = match span {
            ObjectSpan::All => (0, n),
            ObjectSpan::At { offset, len } => {
                if offset + len > n {
                    return Err(io::Error::new(io::ErrorKind::UnexpectedEof, "past the end"));
                }
                (offset, offset + len)
            }
            ObjectSpan::Suffix(s) => (n.saturating_sub(s), n),
        };
        Ok(Some((v[a as usize..b as usize].to_vec(), n)))
    }
}

fn bytes(n: usize, seed: u8) -> Vec<u8> {
    (0..n).map(|i| (i * 13 + seed as usize) as u8).collect()
}

fn config(dir: &Path) -> DiskCacheConfig {
    DiskCacheConfig {
        dir: dir.to_owned(),
        max_bytes: 1 << 30,
    }
}

fn image() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("zarr.json", b"{\"zarr_format\": 3}".to_vec()),
        ("s0/zarr.json", b"{\"shape\": [4]}".to_vec()),
        ("s0/c/0/0/0", bytes(5000, 1)),
        ("s0/c/0/0/1", bytes(700, 2)),
    ]
}

/// Every kind of read, its answers.
fn visit(r: &dyn ObjectReader) -> Vec<String> {
    let mut out = Vec::new();
    for span in [
        ObjectSpan::All,
        ObjectSpan::At {
            offset: 100,
            len: 900,
        },
        ObjectSpan::Suffix(36),
    ] {
        for key in ["s0/c/0/0/0", "s0/c/0/0/1", "s0/c/9/9/9", "s0/zarr.json"] {
            out.push(format!(
                "{key} {span:?}: {:?}",
                r.read_object(key, span).map_err(|e| e.kind())
            ));
        }
    }
    let ranges = [0..10, 4000..4990, 10..4000];
    out.push(format!(
        "{:?}",
        r.read_object_ranges("s0/c/0/0/0", &ranges).unwrap()
    ));
    out.push(format!(
        "{:?}",
        r.read_object_ranges("s0/c/5/5/5", &ranges[..1]).unwrap()
    ));
    out
}

#[test]
fn a_second_visit_reads_only_the_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let direct = visit(&Fake::with(&image()));
    let first = DiskCachedObjects::new(Fake::with(&image()), "id", &config(dir.path())).unwrap();
    assert_eq!(visit(&first), direct);
    let second = DiskCachedObjects::new(Fake::with(&image()), "id", &config(dir.path())).unwrap();
    assert_eq!(visit(&second), direct);
    // The second visit: only the metadata (3 spans of s0/zarr.json), the
    // range read of a missing key (absent objects are cached for
    // `read_object` only) and the range past an object's end (errors are
    // never cached).
    assert_eq!(second.inner().reads(), 3 + 1 + 1, "{:?}", second.stats());
    assert_eq!(second.stats().misses, 0);
    assert!(second.stats().hits >= 9);
}

#[test]
fn a_corrupt_or_torn_entry_is_fetched_again() {
    let dir = tempfile::tempdir().unwrap();
    let direct = visit(&Fake::with(&image()));
    let first = DiskCachedObjects::new(Fake::with(&image()), "id", &config(dir.path())).unwrap();
    visit(&first);
    // Flip a byte in every entry; cut one short.
    let mut n = 0;
    for e in std::fs::read_dir(first.dir()).unwrap().flatten() {
        let p = e.path();
        if p.file_name().unwrap() == "identity" {
            continue;
        }
        let mut b = std::fs::read(&p).unwrap();
        if n == 0 {
            b.truncate(b.len() / 2);
        } else {
            let i = b.len() / 2;
            b[i] ^= 0x10;
        }
        std::fs::write(&p, b).unwrap();
        n += 1;
    }
    assert!(n >= 8);
    let second = DiskCachedObjects::new(Fake::with(&image()), "id", &config(dir.path())).unwrap();
    assert_eq!(visit(&second), direct);
    assert_eq!(second.stats().corrupt, n);
}

#[test]
fn a_changed_image_is_a_new_folder() {
    let dir = tempfile::tempdir().unwrap();
    let a = DiskCachedObjects::for_image(Fake::with(&image()), &config(dir.path())).unwrap();
    let b = DiskCachedObjects::for_image(Fake::with(&image()), &config(dir.path())).unwrap();
    assert_eq!(a.dir(), b.dir());
    let mut changed = image();
    changed[0].1 = b"{\"zarr_format\": 3, \"new\": 1}".to_vec();
    let c = DiskCachedObjects::for_image(Fake::with(&changed), &config(dir.path())).unwrap();
    assert_ne!(a.dir(), c.dir());
    // A v2 image (no zarr.json) has its .zattrs in its identity.
    let v2 = |attrs: &[u8]| {
        DiskCachedObjects::for_image(
            Fake::with(&[(".zattrs", attrs.to_vec())]),
            &config(dir.path()),
        )
        .unwrap()
        .dir()
        .to_owned()
    };
    assert_ne!(v2(b"{\"a\": 1}"), v2(b"{\"a\": 2}"));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Any reads, twice through the cache (the second from the disk), equal
    /// the object's bytes or its error.
    #[test]
    fn reads_through_the_cache_equal_the_objects(
        spans in prop::collection::vec((0u64..3000, 0u64..1500, 0u8..3), 1..12),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let fake = Fake::with(&image());
        for round in 0..2 {
            let cached = DiskCachedObjects::new(Fake::with(&image()), "id", &config(dir.path())).unwrap();
            for &(offset, len, kind) in &spans {
                let span = match kind {
                    0 => ObjectSpan::At { offset, len },
                    1 => ObjectSpan::Suffix(len),
                    _ => ObjectSpan::All,
                };
                let want = fake.read_object("s0/c/0/0/1", span).map_err(|e| e.kind());
                let got = cached.read_object("s0/c/0/0/1", span).map_err(|e| e.kind());
                prop_assert_eq!(got, want, "round {}", round);
            }
            let ranges: Vec<Range<u64>> = spans
                .iter()
                .map(|&(o, l, _)| (o % 5000)..(o % 5000 + l).min(5000))
                .collect();
            prop_assert_eq!(
                cached.read_object_ranges("s0/c/0/0/0", &ranges).unwrap(),
                fake.read_object_ranges("s0/c/0/0/0", &ranges).unwrap()
            );
        }
    }
}
