//! A `BrickSource` for tests: the ball of `refine::tests::ball_info`, bricks filled
//! with a byte derived from the key; injected delays (per read, per metadata
//! call), failing and panicking keys for reads and for metadata (changeable at
//! run time: a key can be "restored"), gates that hold one key's read or metadata
//! call until opened, and a log of calls with the threads that made them.

use crate::config::GpuFormat;
use crate::failures::FetchKind;
use crate::refine::tests::{ball_info, ball_layout};
use brickray_core::{
    BrickError, BrickSource, NodeInfo, NodeKey, OctreeLayout, TexelCaps, U8Filtering,
};
use parking_lot::{Condvar, Mutex};
use std::collections::HashSet;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::thread::ThreadId;
use std::time::Duration;

#[derive(Debug, Default)]
struct Faults {
    failing: HashSet<(FetchKind, NodeKey)>,
    panicking: HashSet<(FetchKind, NodeKey)>,
}

pub(crate) struct TestSource {
    pub(crate) layout: OctreeLayout,
    /// Sleep per brick read.
    pub(crate) delay: Duration,
    /// Sleep per metadata call.
    pub(crate) meta_delay: Duration,
    /// A brick read of this key waits for `open_gate`.
    pub(crate) gate_key: Option<NodeKey>,
    /// A metadata call for this key waits for `open_gate`.
    pub(crate) meta_gate_key: Option<NodeKey>,
    faults: Mutex<Faults>,
    gate: Mutex<bool>,
    gate_cv: Condvar,
    calls: Mutex<Vec<(FetchKind, NodeKey, ThreadId)>>,
    pub(crate) meta_reads: AtomicUsize,
    /// Data nodes above the finest level carry an error record (the same
    /// mid-size error everywhere), as a store's do.
    pub(crate) errors: bool,
    /// What [`BrickSource::batch_size`] answers (1: no batches).
    pub(crate) batch: usize,
    /// The keys of each [`BrickSource::read_bricks`] call.
    pub(crate) batches: Mutex<Vec<Vec<NodeKey>>>,
    /// The keys of each [`BrickSource::nodes`] call.
    pub(crate) node_batches: Mutex<Vec<Vec<NodeKey>>>,
}

pub(crate) fn fill_byte(key: NodeKey) -> u8 {
    (key.level as u32 * 31 + key.x * 7 + key.y * 3 + key.z) as u8
}

/// The GPU format of the tests: u8 as R16Unorm (`raw * 257`: both bytes of a
/// texel equal the raw byte), one sub-cell per brick, 32-byte slot rows.
pub(crate) fn test_gpu(layout: &OctreeLayout) -> GpuFormat {
    let caps = TexelCaps {
        norm16: true,
        float32_filterable: false,
    };
    GpuFormat::for_layout(layout, caps, U8Filtering::Exact, 32, 2048)
}

impl TestSource {
    pub(crate) fn new(dim: u32) -> TestSource {
        TestSource {
            layout: ball_layout(dim),
            delay: Duration::ZERO,
            meta_delay: Duration::ZERO,
            gate_key: None,
            meta_gate_key: None,
            faults: Mutex::new(Faults::default()),
            gate: Mutex::new(false),
            gate_cv: Condvar::new(),
            calls: Mutex::new(Vec::new()),
            meta_reads: AtomicUsize::new(0),
            errors: false,
            batch: 1,
            batches: Mutex::new(Vec::new()),
            node_batches: Mutex::new(Vec::new()),
        }
    }

    /// Makes reads of `kind` for `key` return an I/O error.
    pub(crate) fn fail(&self, kind: FetchKind, key: NodeKey) {
        self.faults.lock().failing.insert((kind, key));
    }

    /// Makes reads of `kind` for `key` panic.
    pub(crate) fn panic_on(&self, kind: FetchKind, key: NodeKey) {
        self.faults.lock().panicking.insert((kind, key));
    }

    /// Ends every injected fault of `key` (the file is "restored").
    pub(crate) fn restore(&self, key: NodeKey) {
        let mut f = self.faults.lock();
        f.failing.retain(|k| k.1 != key);
        f.panicking.retain(|k| k.1 != key);
    }

    pub(crate) fn open_gate(&self) {
        *self.gate.lock() = true;
        self.gate_cv.notify_all();
    }

    fn wait_gate(&self) {
        let mut open = self.gate.lock();
        while !*open {
            self.gate_cv.wait(&mut open);
        }
    }

    /// Brick reads, in order.
    pub(crate) fn reads(&self) -> Vec<NodeKey> {
        self.calls_of(FetchKind::Brick)
    }

    /// Calls of a kind, in order.
    pub(crate) fn calls_of(&self, kind: FetchKind) -> Vec<NodeKey> {
        let calls = self.calls.lock();
        calls.iter().filter(|c| c.0 == kind).map(|c| c.1).collect()
    }

    /// All calls, in order.
    pub(crate) fn calls(&self) -> Vec<(FetchKind, NodeKey)> {
        self.calls.lock().iter().map(|c| (c.0, c.1)).collect()
    }

    /// Calls made by `thread`.
    pub(crate) fn calls_on(&self, thread: ThreadId) -> usize {
        self.calls.lock().iter().filter(|c| c.2 == thread).count()
    }

    fn fault(&self, kind: FetchKind, key: NodeKey) -> Result<(), BrickError> {
        let (fail, panic) = {
            let f = self.faults.lock();
            (
                f.failing.contains(&(kind, key)),
                f.panicking.contains(&(kind, key)),
            )
        };
        if panic {
            panic!("test source panics on the {kind} of {key:?}");
        }
        if fail {
            return Err(BrickError::Io {
                key,
                source: std::io::Error::other("injected failure"),
            });
        }
        Ok(())
    }
}

impl BrickSource for TestSource {
    fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        self.meta_reads.fetch_add(1, Ordering::Relaxed);
        if Some(key) == self.meta_gate_key {
            self.wait_gate();
        }
        if !self.meta_delay.is_zero() {
            std::thread::sleep(self.meta_delay);
        }
        self.calls
            .lock()
            .push((FetchKind::Metadata, key, std::thread::current().id()));
        self.fault(FetchKind::Metadata, key)?;
        if !self.layout.in_volume(key) && key.level >= self.layout.levels {
            return Err(BrickError::OutOfRange { key });
        }
        let mut info = ball_info(&self.layout, key);
        if self.errors
            && info.kind == brickray_core::NodeKind::Data
            && key.level + 1 < self.layout.levels
        {
            info.error = Some(brickray_core::NodeError {
                occupied: 0xffff,
                dev: [u16::MAX / 4; brickray_core::ERROR_BINS],
                rms: [u16::MAX / 8; brickray_core::ERROR_BINS],
                weight: [u16::MAX / 16; brickray_core::ERROR_BINS],
            });
        }
        Ok(info)
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        if Some(key) == self.gate_key {
            self.wait_gate();
        }
        if !self.delay.is_zero() {
            std::thread::sleep(self.delay);
        }
        self.calls
            .lock()
            .push((FetchKind::Brick, key, std::thread::current().id()));
        self.fault(FetchKind::Brick, key)?;
        if out.len() != self.layout.brick_bytes() {
            return Err(BrickError::BufferSize {
                expected: self.layout.brick_bytes(),
                actual: out.len(),
            });
        }
        out.fill(fill_byte(key));
        Ok(())
    }

    fn batch_size(&self) -> usize {
        self.batch
    }

    /// Records the call, then reads each node.
    fn nodes(&self, keys: &[NodeKey]) -> Vec<Result<NodeInfo, BrickError>> {
        self.node_batches.lock().push(keys.to_vec());
        keys.iter().map(|&key| self.node(key)).collect()
    }

    /// Records the batch; a batch holding the gate key waits for the gate or
    /// for `cancel` (then every brick of it is cancelled), as a reader over
    /// the network aborts its requests.
    fn read_bricks(
        &self,
        keys: &[NodeKey],
        outs: &mut [&mut [u8]],
        cancel: &brickray_core::CancelToken,
    ) -> Vec<Result<(), BrickError>> {
        self.batches.lock().push(keys.to_vec());
        if self.gate_key.is_some_and(|g| keys.contains(&g)) {
            let mut open = self.gate.lock();
            while !*open {
                if cancel.is_cancelled() {
                    return keys
                        .iter()
                        .map(|&key| Err(BrickError::Cancelled { key }))
                        .collect();
                }
                self.gate_cv
                    .wait_for(&mut open, std::time::Duration::from_millis(1));
            }
        }
        keys.iter()
            .zip(outs.iter_mut())
            .map(|(&key, out)| self.read_brick(key, out))
            .collect()
    }
}
