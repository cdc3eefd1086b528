//! The byte-range seam: a store opened from any `RangeReader` (memory, a
//! counting or failing reader) reads the same as from its file, in two reads
//! at open, with typed errors for short or failing readers.
#![allow(missing_docs)]

mod common;

use brickray_core::{
    BrickSource, CancelToken, DType, MemRangeReader, NodeKey, RangeRead, RangeReader,
};
use brickray_store::{BuildOptions, Store, StoreError, build};
use common::*;
use proptest::prelude::*;
use std::io;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

fn store_bytes() -> (tempfile::TempDir, std::path::PathBuf, Vec<u8>) {
    let dir = tempfile::tempdir().unwrap();
    let dims = [21, 17, 13];
    let mut r = MemReader::new(dims, DType::U16, test_volume(dims, DType::U16, 5));
    let out = dir.path().join("seam.brs");
    let o = BuildOptions {
        brick: 4,
        apron: 1,
        ..BuildOptions::default()
    };
    build(&mut r, &out, &o).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    (dir, out, bytes)
}

/// Counts reads and bytes; `fail_from`: every read from that one on fails.
#[derive(Debug)]
struct Counting {
    inner: MemRangeReader,
    reads: AtomicUsize,
    batches: AtomicUsize,
    fail_from: Option<usize>,
    log: Mutex<Vec<(u64, usize)>>,
}

impl Counting {
    fn new(bytes: Vec<u8>, fail_from: Option<usize>) -> Counting {
        Counting {
            inner: MemRangeReader::new(bytes),
            reads: AtomicUsize::new(0),
            batches: AtomicUsize::new(0),
            fail_from,
            log: Mutex::new(Vec::new()),
        }
    }
}

impl RangeReader for Counting {
    fn len(&self) -> io::Result<u64> {
        self.inner.len()
    }
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        let n = self.reads.fetch_add(1, Ordering::SeqCst);
        self.log.lock().unwrap().push((offset, buf.len()));
        if self.fail_from.is_some_and(|f| n >= f) {
            return Err(io::Error::new(io::ErrorKind::ConnectionReset, "injected"));
        }
        self.inner.read_exact_at(buf, offset)
    }
    fn read_ranges(&self, ranges: &mut [RangeRead<'_>]) -> io::Result<()> {
        self.batches.fetch_add(1, Ordering::SeqCst);
        for r in ranges {
            self.read_exact_at(r.buf, r.offset)?;
        }
        Ok(())
    }
}

fn assert_same(a: &Store, b: &Store) {
    let an: Vec<_> = a.nodes().collect();
    assert_eq!(an, b.nodes().collect::<Vec<_>>());
    assert_eq!(a.layout(), b.layout());
    let mut x = vec![0u8; a.layout().brick_bytes()];
    let mut y = vec![0u8; a.layout().brick_bytes()];
    for n in &an {
        a.read_brick(n.key, &mut x).unwrap();
        y.fill(0x5A);
        b.read_brick(n.key, &mut y).unwrap();
        assert!(x == y, "{:?}", n.key);
    }
}

#[test]
fn a_store_in_memory_reads_as_its_file_in_two_reads_at_open() {
    let (_dir, path, bytes) = store_bytes();
    let file = Store::open(&path).unwrap();
    assert!(file.has_errors());
    let reader = std::sync::Arc::new(Counting::new(bytes.clone(), None));
    let mem = Store::open_with(reader.clone(), "memory:seam").unwrap();
    // The header, then the table and error sections in one range.
    let log = reader.log.lock().unwrap().clone();
    assert_eq!(log.len(), 2, "{log:?}");
    assert_eq!(log[0], (0, 128));
    assert_eq!(log[1].0 + log[1].1 as u64, bytes.len() as u64);
    assert_eq!(mem.path().to_str(), Some("memory:seam"));
    assert_same(&file, &mem);
    // Batched payload reads: one batch, the same payloads as one by one.
    let keys: Vec<NodeKey> = file.nodes().map(|n| n.key).collect();
    let before = reader.batches.load(Ordering::SeqCst);
    let many = mem.read_compressed_many(&keys).unwrap();
    assert_eq!(reader.batches.load(Ordering::SeqCst), before + 1);
    let with_payload = many.iter().filter(|p| p.is_some()).count();
    assert!(with_payload > 4, "{with_payload}");
    for (k, p) in keys.iter().zip(&many) {
        assert_eq!(&file.read_compressed(*k).unwrap(), p);
    }
    // An out-of-octree key in a batch is a typed error.
    let bad = NodeKey {
        level: 0,
        x: 9,
        y: 0,
        z: 0,
    };
    assert!(matches!(
        mem.read_compressed_many(&[keys[0], bad]),
        Err(StoreError::OutOfRange { .. })
    ));
}

#[test]
fn a_failing_reader_is_a_typed_error() {
    let (_dir, _path, bytes) = store_bytes();
    // Fails at open (the header, then the tail).
    for fail_from in [0, 1] {
        match Store::open_with(Counting::new(bytes.clone(), Some(fail_from)), "memory:x") {
            Err(StoreError::Io { path, source }) => {
                assert_eq!(path.to_str(), Some("memory:x"));
                assert_eq!(source.kind(), io::ErrorKind::ConnectionReset);
            }
            other => panic!("{other:?}"),
        }
    }
    // Fails after open: every payload read is a typed node error, never a
    // brick; nodes without a payload still read.
    let s = Store::open_with(Counting::new(bytes.clone(), Some(2)), "memory:x").unwrap();
    let mut out = vec![0u8; s.layout().brick_bytes()];
    let mut failed = 0;
    for n in s.nodes().collect::<Vec<_>>() {
        match s.read(n.key, &mut out) {
            Ok(()) => assert_eq!(n.payload_len, 0),
            Err(StoreError::NodeIo { key, .. }) => {
                assert_eq!(key, n.key);
                failed += 1;
            }
            Err(e) => panic!("{e}"),
        }
    }
    assert!(failed > 4);
    let keys: Vec<NodeKey> = s.nodes().map(|n| n.key).collect();
    assert!(s.read_compressed_many(&keys).is_err());
}

#[test]
fn a_flipped_payload_byte_fails_its_checksum_in_a_batch_too() {
    let (_dir, path, mut bytes) = store_bytes();
    let file = Store::open(&path).unwrap();
    // The payloads tile the file from the header's end on.
    bytes[128] ^= 0x40;
    let mem = Store::open_with(MemRangeReader::new(bytes), "memory:flipped").unwrap();
    let keys: Vec<NodeKey> = file.nodes().map(|n| n.key).collect();
    let r = mem.read_compressed_many(&keys);
    assert!(
        matches!(r, Err(StoreError::PayloadChecksum { .. })),
        "{r:?}"
    );
}

/// A reader that says it is remote (each read a round trip).
#[derive(Debug)]
struct Remote(Counting);

impl RangeReader for Remote {
    fn len(&self) -> io::Result<u64> {
        self.0.len()
    }
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        self.0.read_exact_at(buf, offset)
    }
    fn read_ranges(&self, ranges: &mut [RangeRead<'_>]) -> io::Result<()> {
        self.0.read_ranges(ranges)
    }
    fn read_ranges_cancellable(
        &self,
        ranges: &mut [RangeRead<'_>],
        cancel: &CancelToken,
    ) -> io::Result<()> {
        if cancel.is_cancelled() {
            return Err(io::Error::new(io::ErrorKind::Interrupted, "cancelled"));
        }
        self.read_ranges(ranges)
    }
    fn is_remote(&self) -> bool {
        true
    }
}

#[test]
fn bricks_read_in_batches_over_a_remote_reader_equal_single_reads() {
    let (_dir, path, mut bytes) = store_bytes();
    let file = Store::open(&path).unwrap();
    assert_eq!(
        file.batch_size(),
        1,
        "a local file reads one brick per call"
    );
    let keys: Vec<NodeKey> = file.nodes().map(|n| n.key).collect();
    let brick = file.layout().brick_bytes();
    let single: Vec<Vec<u8>> = keys
        .iter()
        .map(|&k| {
            let mut out = vec![0u8; brick];
            file.read_brick(k, &mut out).unwrap();
            out
        })
        .collect();
    let read_all = |s: &Store| {
        let mut bufs = vec![vec![0u8; brick]; keys.len()];
        let mut outs: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        let results = s.read_bricks(&keys, &mut outs, &CancelToken::new());
        (bufs, results)
    };
    let reader = std::sync::Arc::new(Remote(Counting::new(bytes.clone(), None)));
    let remote = Store::open_with(reader.clone(), "memory:remote").unwrap();
    assert_eq!(remote.batch_size(), brickray_store::STORE_BATCH);
    let before = reader.0.batches.load(Ordering::SeqCst);
    let (bufs, results) = read_all(&remote);
    assert_eq!(reader.0.batches.load(Ordering::SeqCst), before + 1);
    assert!(results.iter().all(Result::is_ok));
    assert_eq!(bufs, single);
    // A flipped payload byte fails its node only; every other brick reads
    // as it does alone.
    bytes[128] ^= 0x40;
    let flipped = Store::open_with(Remote(Counting::new(bytes, None)), "memory:f").unwrap();
    let (bufs, results) = read_all(&flipped);
    let failed: Vec<usize> = (0..keys.len()).filter(|&i| results[i].is_err()).collect();
    assert_eq!(failed.len(), 1, "{results:?}");
    for i in (0..keys.len()).filter(|i| !failed.contains(i)) {
        assert_eq!(bufs[i], single[i], "{:?}", keys[i]);
    }
    // A buffer of the wrong size is that brick's error.
    let mut small = vec![0u8; 3];
    let mut right = vec![0u8; brick];
    let mut outs: Vec<&mut [u8]> = vec![&mut small, &mut right];
    let data = file.nodes().find(|n| n.payload_len > 0).unwrap().key;
    let r = remote.read_bricks(&[data, data], &mut outs, &CancelToken::new());
    assert!(r[0].is_err() && r[1].is_ok(), "{r:?}");
    // A cancelled batch fails every brick as cancelled, without reading
    // node by node.
    let cancel = CancelToken::new();
    cancel.cancel();
    let before = reader.0.reads.load(Ordering::SeqCst);
    let mut bufs = vec![vec![0u8; brick]; keys.len()];
    let mut outs: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
    let r = remote.read_bricks(&keys, &mut outs, &cancel);
    let data_nodes: Vec<usize> = (0..keys.len())
        .filter(|&i| remote.record(keys[i]).unwrap().payload_len > 0)
        .collect();
    for (i, r) in r.iter().enumerate() {
        if data_nodes.contains(&i) {
            assert!(
                matches!(r, Err(brickray_core::BrickError::Cancelled { .. })),
                "{r:?}"
            );
        } else {
            // Uniform and empty nodes need no read.
            assert!(r.is_ok(), "{r:?}");
        }
    }
    assert_eq!(reader.0.reads.load(Ordering::SeqCst), before);
}

/// One store for every proptest case (its bytes and an open copy).
fn shared() -> &'static (Vec<u8>, Store) {
    static S: std::sync::OnceLock<(Vec<u8>, Store)> = std::sync::OnceLock::new();
    S.get_or_init(|| {
        let (_dir, _path, bytes) = store_bytes();
        let store = Store::open_with(MemRangeReader::new(bytes.clone()), "memory:ref").unwrap();
        (bytes, store)
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Any prefix of a store, any byte flipped: a typed error or the same
    /// store, never a panic, never a different brick.
    #[test]
    fn cut_or_flipped_stores_in_memory_never_panic(cut in 0.0f64..1.0, flip in proptest::option::of((0usize..1 << 20, 1u8..=255))) {
        let (bytes, file) = shared();
        let mut b = bytes.clone();
        let keep = ((b.len() as f64) * cut) as usize;
        if let Some((i, x)) = flip {
            let i = i % b.len();
            b[i] ^= x;
        } else {
            b.truncate(keep);
        }
        if let Ok(s) = Store::open_with(MemRangeReader::new(b), "memory:p") {
            let mut x = vec![0u8; file.layout().brick_bytes()];
            let mut y = x.clone();
            for n in file.nodes() {
                file.read(n.key, &mut x).unwrap();
                if s.read(n.key, &mut y).is_ok() {
                    prop_assert!(x == y, "{:?}", n.key);
                }
            }
        }
    }
}
