use super::*;
use brickray_core::NodeKey;

/// A raw + JSON sidecar of three planar u16 channels of 20x18x12 (channel
/// `c` holds `c * 1000 + (x + 2y + 3z) % 101`).
fn write_three(dir: &Path) -> PathBuf {
    let mut bytes = Vec::new();
    for c in 0..3u32 {
        for z in 0..12u32 {
            for y in 0..18u32 {
                for x in 0..20u32 {
                    bytes.extend_from_slice(
                        &((c * 1000 + (x + 2 * y + 3 * z) % 101) as u16).to_le_bytes(),
                    );
                }
            }
        }
    }
    std::fs::write(dir.join("c.raw"), bytes).unwrap();
    let json = dir.join("c.json");
    std::fs::write(
        &json,
        r#"{"dims": [20, 18, 12], "dtype": "u16", "spacing": [1, 1, 2], "file": "c.raw", "channels": 3}"#,
    )
    .unwrap();
    json
}

/// A channel set built from a multi-channel input records one store per
/// channel and opens as one source whose bricks interleave the stores'
/// (each channel's value range its own); the channels' descriptions come
/// back as written.
#[test]
fn a_channel_set_records_one_store_per_channel() {
    let dir = tempfile::tempdir().unwrap();
    let json = write_three(dir.path());
    let readers = brickray_io::open_channels(&json, &Default::default()).unwrap();
    let set = dir.path().join("cells.channels.json");
    let opts = BuildOptions {
        brick: 8,
        ..Default::default()
    };
    let reports = build_channels(readers, &set, &opts).unwrap();
    assert_eq!(reports.len(), 3);
    for c in 0..3 {
        assert!(dir.path().join(format!("cells.c{c}.brs")).exists());
    }
    let opened = open_channels(&set).unwrap();
    assert_eq!(opened.source.len(), 3);
    assert_eq!(opened.stores[2], dir.path().join("cells.c2.brs"));
    let l = opened.source.layout();
    let ranges = l.channel_ranges().to_vec();
    assert_eq!(ranges.len(), 3);
    assert!(ranges.windows(2).all(|w| w[1][0] >= w[0][1]), "{ranges:?}");
    let key = NodeKey::new(l.levels - 1, 1, 0, 0);
    let mut b = vec![0u8; l.brick_bytes()];
    opened.source.read_brick(key, &mut b).unwrap();
    let mut parts = Vec::new();
    for c in 0..3 {
        let s = crate::open(dir.path().join(format!("cells.c{c}.brs"))).unwrap();
        let mut p = vec![0u8; s.layout().brick_bytes()];
        s.read_brick(key, &mut p).unwrap();
        parts.push(p);
    }
    for (i, v) in b.chunks_exact(6).enumerate() {
        for c in 0..3 {
            assert_eq!(&v[2 * c..2 * c + 2], &parts[c][2 * i..2 * i + 2]);
        }
    }
    assert_eq!(opened.info, vec![ChannelInfo::default(); 3]);
    // Descriptions are kept; a store path may be absolute.
    let info = vec![
        ChannelInfo {
            label: Some("nuclei".into()),
            color: Some([0.0, 1.0, 0.0]),
            window: Some([10.0, 90.0]),
            active: false,
        },
        ChannelInfo::default(),
    ];
    let two = dir.path().join("two.channels.json");
    write_channel_set(&two, &opened.stores[..2], &info).unwrap();
    assert_eq!(open_channels(&two).unwrap().info, info);
}

#[test]
fn bad_channel_sets_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.channels.json");
    let bad = |text: &str| {
        std::fs::write(&p, text).unwrap();
        open_channels(&p).unwrap_err()
    };
    assert!(matches!(bad("not json"), StoreError::ChannelSet { .. }));
    assert!(matches!(
        bad(r#"{"format": "other", "version": 1, "channels": []}"#),
        StoreError::ChannelSet { .. }
    ));
    // A missing store: the store's own error.
    assert!(matches!(
        bad(
            r#"{"format": "brickray-channels", "version": 1, "channels": [{"store": "none.brs"}]}"#
        ),
        StoreError::Io { .. }
    ));
    // No channel.
    assert!(matches!(
        bad(r#"{"format": "brickray-channels", "version": 1, "channels": []}"#),
        StoreError::ChannelSet { .. }
    ));
    // A name without the suffix, and counts that do not match.
    let json = write_three(dir.path());
    let readers = brickray_io::open_channels(&json, &Default::default()).unwrap();
    assert!(matches!(
        build_channels(
            readers,
            &dir.path().join("x.json"),
            &BuildOptions::default()
        ),
        Err(StoreError::ChannelSet { .. })
    ));
    assert!(matches!(
        write_channel_set(&p, &[], &[]),
        Err(StoreError::ChannelSet { .. })
    ));
    assert_eq!(
        channel_store_path(Path::new("/d/cells.channels.json"), 2),
        Path::new("/d/cells.c2.brs")
    );
    assert!(is_channel_set(Path::new("a/B.Channels.JSON")));
    assert!(!is_channel_set(Path::new("a/b.json")));
}
