//! A `BrickSource` for tests: the ball of `refine::tests::ball_info`, bricks filled
//! with a byte derived from the key, optional per-read delay, failing and panicking
//! keys, a gate that holds one key's read until opened, and a log of reads.

use crate::refine::tests::{ball_info, ball_layout};
use brickray_core::{BrickError, BrickSource, NodeInfo, NodeKey, OctreeLayout};
use parking_lot::{Condvar, Mutex};
use std::collections::HashSet;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

pub(crate) struct TestSource {
    pub(crate) layout: OctreeLayout,
    pub(crate) delay: Duration,
    pub(crate) failing: HashSet<NodeKey>,
    pub(crate) panicking: HashSet<NodeKey>,
    pub(crate) gate_key: Option<NodeKey>,
    gate: Mutex<bool>,
    gate_cv: Condvar,
    pub(crate) reads: Mutex<Vec<NodeKey>>,
    pub(crate) meta_reads: AtomicUsize,
}

pub(crate) fn fill_byte(key: NodeKey) -> u8 {
    (key.level as u32 * 31 + key.x * 7 + key.y * 3 + key.z) as u8
}

impl TestSource {
    pub(crate) fn new(dim: u32) -> TestSource {
        TestSource {
            layout: ball_layout(dim),
            delay: Duration::ZERO,
            failing: HashSet::new(),
            panicking: HashSet::new(),
            gate_key: None,
            gate: Mutex::new(false),
            gate_cv: Condvar::new(),
            reads: Mutex::new(Vec::new()),
            meta_reads: AtomicUsize::new(0),
        }
    }

    pub(crate) fn open_gate(&self) {
        *self.gate.lock() = true;
        self.gate_cv.notify_all();
    }

    pub(crate) fn reads(&self) -> Vec<NodeKey> {
        self.reads.lock().clone()
    }
}

impl BrickSource for TestSource {
    fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        self.meta_reads.fetch_add(1, Ordering::Relaxed);
        if !self.layout.in_volume(key) && key.level >= self.layout.levels {
            return Err(BrickError::OutOfRange { key });
        }
        Ok(ball_info(&self.layout, key))
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        if Some(key) == self.gate_key {
            let mut open = self.gate.lock();
            while !*open {
                self.gate_cv.wait(&mut open);
            }
        }
        if !self.delay.is_zero() {
            std::thread::sleep(self.delay);
        }
        self.reads.lock().push(key);
        if self.panicking.contains(&key) {
            panic!("test source panics on {key:?}");
        }
        if self.failing.contains(&key) {
            return Err(BrickError::Io {
                key,
                source: std::io::Error::other("injected failure"),
            });
        }
        if out.len() != self.layout.brick_bytes() {
            return Err(BrickError::BufferSize {
                expected: self.layout.brick_bytes(),
                actual: out.len(),
            });
        }
        out.fill(fill_byte(key));
        Ok(())
    }
}
