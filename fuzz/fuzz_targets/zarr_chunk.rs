//! Arbitrary bytes as one chunk (or shard) of an OME-Zarr image: the first
//! byte picks the array's codecs (none, zstd, gzip, blosc, zstd + crc32c, a
//! shard with its index at the end, zarr v2 zstd), the rest is the file of
//! chunk (0, 0, 0); the other chunks are missing (fill value). Any outcome
//! but a panic, an abort, a hang or a huge allocation is fine; a volume that
//! reads keeps the reader's promises, and the image is also served as bricks.
#![no_main]

#[path = "common.rs"]
mod common;

use brickray_core::{BrickSource, NodeKey};
use libfuzzer_sys::fuzz_target;

const GROUP_V3: &str = r#"{"zarr_format":3,"node_type":"group","attributes":{"ome":{"version":"0.5","multiscales":[{"axes":[{"name":"z","type":"space"},{"name":"y","type":"space"},{"name":"x","type":"space"}],"datasets":[{"path":"s0","coordinateTransformations":[{"type":"scale","scale":[2.0,1.0,1.0]}]}]}]}}}"#;
const ZATTRS_V2: &str = r#"{"multiscales":[{"version":"0.4","axes":[{"name":"z","type":"space"},{"name":"y","type":"space"},{"name":"x","type":"space"}],"datasets":[{"path":"s0","coordinateTransformations":[{"type":"scale","scale":[2.0,1.0,1.0]}]}]}]}"#;

/// The array's codecs (zarr v3 `codecs` lists), by the input's first byte.
fn codecs(kind: u8) -> &'static str {
    match kind % 6 {
        0 => r#"[{"name":"bytes","configuration":{"endian":"little"}}]"#,
        1 => r#"[{"name":"bytes","configuration":{"endian":"little"}},{"name":"zstd","configuration":{"level":3,"checksum":false}}]"#,
        2 => r#"[{"name":"bytes","configuration":{"endian":"little"}},{"name":"gzip","configuration":{"level":5}}]"#,
        3 => r#"[{"name":"bytes","configuration":{"endian":"little"}},{"name":"blosc","configuration":{"cname":"lz4","clevel":5,"shuffle":"shuffle","typesize":2,"blocksize":0}}]"#,
        4 => r#"[{"name":"bytes","configuration":{"endian":"little"}},{"name":"zstd","configuration":{"level":3,"checksum":false}},{"name":"crc32c"}]"#,
        _ => r#"[{"name":"sharding_indexed","configuration":{"chunk_shape":[2,3,4],"codecs":[{"name":"bytes","configuration":{"endian":"little"}},{"name":"zstd","configuration":{"level":3,"checksum":false}}],"index_codecs":[{"name":"bytes","configuration":{"endian":"little"}},{"name":"crc32c"}],"index_location":"end"}}]"#,
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&kind, chunk)) = data.split_first() else {
        return;
    };
    let root = common::scratch().join("f.ome.zarr");
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(root.join("s0/c/0/0")).expect("scratch folder");
    if kind >= 250 {
        // zarr v2 (OME-Zarr 0.4), zstd
        std::fs::write(root.join(".zgroup"), r#"{"zarr_format":2}"#).expect("write");
        std::fs::write(root.join(".zattrs"), ZATTRS_V2).expect("write");
        std::fs::write(
            root.join("s0/.zarray"),
            r#"{"zarr_format":2,"shape":[4,6,8],"chunks":[2,3,4],"dtype":"<u2","compressor":{"id":"zstd","level":3},"fill_value":0,"order":"C","filters":null,"dimension_separator":"."}"#,
        )
        .expect("write");
        std::fs::write(root.join("s0/0.0.0"), chunk).expect("write the input");
    } else {
        let sharded = kind % 6 == 5;
        let chunk_shape = if sharded { "[4,6,8]" } else { "[2,3,4]" };
        std::fs::write(root.join("zarr.json"), GROUP_V3).expect("write");
        std::fs::write(
            root.join("s0/zarr.json"),
            format!(
                r#"{{"zarr_format":3,"node_type":"array","shape":[4,6,8],"data_type":"uint16","chunk_grid":{{"name":"regular","configuration":{{"chunk_shape":{chunk_shape}}}}},"chunk_key_encoding":{{"name":"default","configuration":{{"separator":"/"}}}},"fill_value":0,"codecs":{}}}"#,
                codecs(kind)
            ),
        )
        .expect("write");
        std::fs::write(root.join("s0/c/0/0/0"), chunk).expect("write the input");
    }
    if let Ok(v) = brickray_io::read_volume(&root) {
        common::check_volume(&v);
    }
    if let Ok(src) =
        brickray_io::zarr::ZarrBrickSource::open(&root, &Default::default(), 4, 1, None)
    {
        let mut buf = vec![0u8; src.layout().brick_bytes()];
        let key = NodeKey::new(src.layout().levels - 1, 0, 0, 0);
        let _ = src.node(key);
        let _ = src.read_brick(key, &mut buf);
    }
});
