//! Arbitrary bytes as a NIfTI file, read as `f.nii` and, gzip-compressed
//! by the target, as `f.nii.gz`; the bytes themselves also as `g.nii.gz`
//! (the gzip stream fuzzed). Any outcome but a panic, an abort, a hang or a
//! huge allocation is fine; a volume that reads keeps the reader's promises.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use std::io::Write;

fuzz_target!(|data: &[u8]| {
    let dir = common::scratch();
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    gz.write_all(data).expect("gzip in memory");
    let gz = gz.finish().expect("gzip in memory");
    for (name, bytes) in [("f.nii", data), ("f.nii.gz", &gz[..]), ("g.nii.gz", data)] {
        let p = dir.join(name);
        std::fs::write(&p, bytes).expect("write the input");
        if let Ok(v) = brickray_io::read_volume(&p) {
            common::check_volume(&v);
        }
    }
});
