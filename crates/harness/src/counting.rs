//! A brick source that counts reads per node, over a store built from a
//! volume: what tests of shared pools and caches count.

use brickray_core::{BrickError, BrickSource, NodeInfo, NodeKey, OctreeLayout, Volume};
use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

/// Forwards to `inner`, counting each node's `read_brick` calls.
pub struct CountingSource {
    /// The source read.
    pub inner: Arc<dyn BrickSource>,
    /// Reads per node so far.
    pub reads: Mutex<HashMap<NodeKey, u32>>,
}

impl CountingSource {
    /// Builds `vol` into a store of `brick`-voxel bricks at `dir/name.brs`
    /// and counts the reads of the opened store. Panics on a failed build
    /// (a test helper).
    pub fn store(vol: Volume, dir: &Path, name: &str, brick: u32) -> Arc<CountingSource> {
        let path = dir.join(format!("{name}.brs"));
        let mut reader = brickray_io::MemoryReader::new(vol, "memory");
        let opt = brickray_store::BuildOptions {
            brick,
            ..Default::default()
        };
        brickray_store::build(&mut reader, &path, &opt).expect("build the test store");
        Arc::new(CountingSource {
            inner: Arc::new(brickray_store::open(&path).expect("open the test store")),
            reads: Mutex::new(HashMap::new()),
        })
    }

    /// A copy of the reads so far.
    pub fn reads(&self) -> HashMap<NodeKey, u32> {
        self.reads.lock().map(|r| r.clone()).unwrap_or_default()
    }
}

impl std::fmt::Debug for CountingSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CountingSource")
            .field("layout", self.inner.layout())
            .field("reads", &self.reads)
            .finish()
    }
}

impl BrickSource for CountingSource {
    fn layout(&self) -> &OctreeLayout {
        self.inner.layout()
    }
    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        self.inner.node(key)
    }
    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        if let Ok(mut r) = self.reads.lock() {
            *r.entry(key).or_insert(0) += 1;
        }
        self.inner.read_brick(key, out)
    }
    fn has_spread(&self) -> bool {
        self.inner.has_spread()
    }
    fn read_spread(&self, key: NodeKey, out: &mut [u16]) -> Result<(), BrickError> {
        self.inner.read_spread(key, out)
    }
}
