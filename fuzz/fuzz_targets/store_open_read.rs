//! Arbitrary bytes as a brick store: open, then read every node. Any outcome
//! but a panic, an abort or a hang is fine; a store that opens must answer
//! every read of its own nodes with a brick or a typed error.
#![no_main]

#[path = "common.rs"]
mod common;

use brickray_core::{BrickSource, NodeKey};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch().join("store.brick");
    std::fs::write(&path, data).expect("write the input");
    let Ok(store) = brickray_store::open(&path) else {
        return;
    };
    let mut buf = vec![0u8; store.layout().brick_bytes()];
    let side = store.layout().stored_side() as usize;
    let mut spreads = vec![0u16; side * side * side];
    let keys: Vec<NodeKey> = store.nodes().map(|n| n.key).collect();
    for key in keys {
        let _ = store.node(key);
        // Spreads (format version 7) that read are never negative nor NaN.
        if BrickSource::read_spread(&store, key, &mut spreads).is_ok() {
            assert!(spreads.iter().all(|&s| s <= 0x7c00), "{key:?}");
        }
        let _ = store.children(key);
        if let Ok(Some(payload)) = store.read_compressed(key) {
            let _ = store.decode(key, &payload, &mut buf);
        }
        if store.read_brick(key, &mut buf).is_ok() {
            let info = store.node(key).expect("a node that reads has metadata");
            // A brick that reads lies within its node's recorded range.
            let dtype = store.layout().dtype();
            if let brickray_core::NodeKind::Data = info.kind {
                for v in dtype.decode_le(&buf) {
                    assert!(
                        v >= info.min && v <= info.max,
                        "{key:?}: {v} outside {info:?}"
                    );
                }
            }
        }
    }
    // Keys outside the table and outside the octree.
    let levels = store.levels();
    for key in [
        NodeKey::ROOT,
        NodeKey::new(levels, 0, 0, 0),
        NodeKey::new(levels - 1, u32::MAX, 0, 0),
    ] {
        let _ = store.node(key);
        let _ = store.read_brick(key, &mut buf);
        let _ = BrickSource::read_spread(&store, key, &mut spreads);
    }
    let _ = store.read_brick(NodeKey::ROOT, &mut []);
    let _ = BrickSource::read_spread(&store, NodeKey::ROOT, &mut []);
});
