//! Arbitrary bytes as a raw + JSON sidecar (`s.json`), beside data files of a
//! few sizes (`s.raw`, `d.raw`). Any outcome but a panic, an abort, a hang or
//! a huge allocation is fine; a volume that reads keeps the reader's promises.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let dir = common::scratch();
    let raw = dir.join("s.raw");
    if !raw.exists() {
        // u16 5x4x3, and 64 bytes of f32 ones.
        std::fs::write(
            &raw,
            (0u16..60)
                .flat_map(|v| v.to_le_bytes())
                .collect::<Vec<u8>>(),
        )
        .expect("write s.raw");
        std::fs::write(dir.join("d.raw"), [0u8, 0, 128, 63].repeat(16)).expect("write d.raw");
    }
    let json = dir.join("s.json");
    std::fs::write(&json, data).expect("write the input");
    if let Ok(v) = brickray_io::read_volume(&json) {
        common::check_volume(&v);
    }
});
