//! Arbitrary bytes as a TIFF stack (`f.tif`). Any outcome but a panic, an
//! abort, a hang or a huge allocation is fine; a volume that reads keeps
//! the reader's promises.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let p = common::scratch().join("f.tif");
    std::fs::write(&p, data).expect("write the input");
    if let Ok(v) = brickray_io::read_volume(&p) {
        common::check_volume(&v);
    }
});
