use super::*;

#[test]
fn inputs_parse() {
    assert_eq!(Input::parse("procedural").unwrap(), Input::Procedural(4096));
    assert_eq!(
        Input::parse("procedural:256").unwrap(),
        Input::Procedural(256)
    );
    assert!(Input::parse("procedural:0").is_err());
    assert!(Input::parse("procedural:x").is_err());
    assert_eq!(Input::parse("bulb").unwrap(), Input::Bulb(4096));
    assert_eq!(Input::parse("bulb:512").unwrap(), Input::Bulb(512));
    assert!(Input::parse("bulb:").is_err());
    assert!(Input::parse("bulb:99999999").is_err());
    assert_eq!(
        Input::parse("a/b.json").unwrap(),
        Input::Path("a/b.json".into())
    );
}

fn write_sphere(dir: &Path) -> PathBuf {
    let v = brickray::core::synthetic::sphere(24);
    let raw = dir.join("s.raw");
    std::fs::write(&raw, v.data().as_bytes()).unwrap();
    let json = dir.join("s.json");
    std::fs::write(
        &json,
        r#"{"dims": [24, 24, 24], "dtype": "u8", "spacing": [1, 1, 1], "file": "s.raw", "value_range": [0, 255]}"#,
    )
    .unwrap();
    json
}

/// Small files load whole, with a histogram of every voxel; with a lower
/// in-core limit the same file is built into a store (progress reaches the
/// total) and streamed, and a second open reuses the store.
#[test]
fn small_files_load_whole_and_large_ones_stream() {
    let dir = tempfile::tempdir().unwrap();
    let json = write_sphere(dir.path());
    let mut opts = OpenOptions {
        in_core_max_bytes: 1 << 20,
        max_3d_side: 2048,
        store_dir: dir.path().join("stores"),
        labels: false,
        spread: false,
    };
    let input = Input::Path(json);
    let p = Progress::default();
    let l = open(&input, &opts, &p).unwrap();
    assert!(matches!(l.volume, Opened::InCore(_)));
    assert_eq!(l.histogram.bins.iter().sum::<u64>(), 24 * 24 * 24);
    assert_eq!(p.fraction(), 1.0);

    opts.in_core_max_bytes = 100;
    let p = Progress::default();
    let l = open(&input, &opts, &p).unwrap();
    assert!(matches!(l.volume, Opened::Streamed(_)), "{}", l.note);
    assert!(l.note.contains("built"), "{}", l.note);
    assert_eq!(p.fraction(), 1.0);
    assert!(l.histogram.bins.iter().sum::<u64>() > 0);
    let l = open(&input, &opts, &Progress::default()).unwrap();
    assert!(l.note.contains("reused"), "{}", l.note);
}

/// A file placed in patient space keeps its placement in core and
/// through the store built for it; a store built without one (as before
/// stores kept placements) is built again rather than reused.
#[test]
fn a_placement_survives_the_store_and_an_old_store_is_rebuilt() {
    let dir = tempfile::tempdir().unwrap();
    let plain = write_sphere(dir.path());
    // The same voxels, an LPS placement (rows toward the patient's
    // left, columns toward posterior, slices toward the head).
    let placed = dir.path().join("placed.json");
    std::fs::write(
        &placed,
        r#"{"dims": [24, 24, 24], "dtype": "u8", "spacing": [0.5, 0.5, 2], "file": "s.raw",
            "value_range": [0, 255], "affine_space": "LPS",
            "affine": [[0.5, 0, 0, -6], [0, 0.5, 0, 4], [0, 0, 2, 10], [0, 0, 0, 1]]}"#,
    )
    .unwrap();
    let mut opts = OpenOptions {
        in_core_max_bytes: 1 << 20,
        max_3d_side: 2048,
        store_dir: dir.path().join("stores"),
        labels: false,
        spread: false,
    };
    let code = |l: &Loaded| l.placement.and_then(|p| p.orientation()).map(|o| o.code());
    let l = open(&Input::Path(placed.clone()), &opts, &Progress::default()).unwrap();
    assert!(matches!(l.volume, Opened::InCore(_)));
    assert_eq!(code(&l).as_deref(), Some("LPS"));
    opts.in_core_max_bytes = 100;
    let l = open(&Input::Path(placed.clone()), &opts, &Progress::default()).unwrap();
    assert!(l.note.contains("built"), "{}", l.note);
    assert_eq!(code(&l).as_deref(), Some("LPS"));
    // An old store in its place: no placement, newer than the input.
    let store = opts.store_dir.join("placed.brs");
    let mut reader = brickray::io::open(&plain).unwrap();
    brickray::store::build(reader.as_mut(), &store, &Default::default()).unwrap();
    assert!(brickray::store::open(&store).unwrap().placement().is_none());
    let l = open(&Input::Path(placed), &opts, &Progress::default()).unwrap();
    assert!(l.note.contains("built"), "{}", l.note);
    assert_eq!(code(&l).as_deref(), Some("LPS"));
    // A file without a placement reuses its store.
    let plain_input = Input::Path(plain);
    open(&plain_input, &opts, &Progress::default()).unwrap();
    let l = open(&plain_input, &opts, &Progress::default()).unwrap();
    assert!(l.note.contains("reused"), "{}", l.note);
    assert_eq!(code(&l), None);
}

/// `--spread`: the store built for a large file records spreads; a store
/// without them is built again, one with them is reused (with or without
/// the option) and drawn with them.
#[test]
fn spreads_are_recorded_when_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let input = Input::Path(write_sphere(dir.path()));
    let mut opts = OpenOptions {
        in_core_max_bytes: 100,
        max_3d_side: 2048,
        store_dir: dir.path().join("stores"),
        labels: false,
        spread: false,
    };
    let spreads = |l: &Loaded| match &l.volume {
        Opened::Streamed(s) => s.has_spread(),
        _ => panic!("not streamed: {}", l.note),
    };
    let l = open(&input, &opts, &Progress::default()).unwrap();
    assert!(l.note.contains("built") && !spreads(&l), "{}", l.note);
    opts.spread = true;
    let l = open(&input, &opts, &Progress::default()).unwrap();
    assert!(l.note.contains("built") && spreads(&l), "{}", l.note);
    let l = open(&input, &opts, &Progress::default()).unwrap();
    assert!(l.note.contains("reused") && spreads(&l), "{}", l.note);
    opts.spread = false;
    let l = open(&input, &opts, &Progress::default()).unwrap();
    assert!(l.note.contains("reused") && spreads(&l), "{}", l.note);
}

#[test]
fn bad_inputs_are_errors() {
    let opts = OpenOptions {
        in_core_max_bytes: 1 << 20,
        max_3d_side: 2048,
        store_dir: std::env::temp_dir(),
        labels: false,
        spread: false,
    };
    let p = Progress::default();
    let missing = Input::Path("/nonexistent/v.json".into());
    assert!(matches!(open(&missing, &opts, &p), Err(OpenError::Io(_))));
    let bad_store = Input::Path("/nonexistent/v.brs".into());
    assert!(matches!(
        open(&bad_store, &opts, &p),
        Err(OpenError::Store(_))
    ));
    let unknown = Input::Path("v.xyz".into());
    assert!(open(&unknown, &opts, &p).is_err());
    // A URL is opened as a remote store: one without a bucket is refused
    // before any request, with the URL in the message.
    #[cfg(feature = "remote")]
    for url in ["s3:///v.brs", "gs:///v.brs"] {
        let e = open(&Input::parse(url).unwrap(), &opts, &p).err().unwrap();
        assert!(matches!(e, OpenError::Store(_)), "{url}: {e}");
        assert!(e.to_string().contains(url), "{url}: {e}");
    }
}

/// The Range HTTP test server's URL (scripts/test.sh starts it and sets
/// BRICKRAY_TEST_HTTP and BRICKRAY_ALLOW_HTTP=1); `None` (a failure with
/// `CI=true`) without it.
#[cfg(feature = "remote")]
fn test_http() -> Option<String> {
    let ci = std::env::var("CI").is_ok_and(|v| v == "true");
    match (
        std::env::var("BRICKRAY_TEST_HTTP"),
        std::env::var("BRICKRAY_ALLOW_HTTP"),
    ) {
        (Ok(http), Ok(_)) => Some(http),
        _ => {
            assert!(
                !ci,
                "CI=true but BRICKRAY_TEST_HTTP or BRICKRAY_ALLOW_HTTP is unset"
            );
            eprintln!("skipping: BRICKRAY_TEST_HTTP or BRICKRAY_ALLOW_HTTP is unset");
            None
        }
    }
}

/// PUTs `bytes` at `url` on the test server.
#[cfg(feature = "remote")]
fn put_file(url: &str, bytes: &[u8]) {
    use std::io::{Read, Write};
    let rest = url.strip_prefix("http://").unwrap();
    let (host, path) = rest.split_once('/').unwrap();
    let mut c = std::net::TcpStream::connect(host).unwrap();
    write!(
        c,
        "PUT /{path} HTTP/1.1\r\nHost: {host}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        bytes.len()
    )
    .unwrap();
    c.write_all(bytes).unwrap();
    let mut resp = String::new();
    let _ = c.read_to_string(&mut resp);
    assert!(resp.starts_with("HTTP/1.1 201"), "{resp}");
}

/// PUTs every file under `dir` at `url` plus its path below `root`.
#[cfg(feature = "remote")]
fn put_tree(dir: &Path, root: &Path, url: &str) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            put_tree(&p, root, url);
            continue;
        }
        let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
        put_file(&format!("{url}/{rel}"), &std::fs::read(&p).unwrap());
    }
}

/// A store's URL on the Range HTTP test server (scripts/test.sh starts
/// it and allows plain HTTP for this test with BRICKRAY_ALLOW_HTTP=1)
/// opens as the local store does: the same description and histogram.
#[cfg(feature = "remote")]
#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP and BRICKRAY_ALLOW_HTTP=1 (scripts/test.sh sets both)"]
fn a_store_url_opens_as_its_file() {
    let Some(http) = test_http() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let json = write_sphere(dir.path());
    let opts = OpenOptions {
        in_core_max_bytes: 0,
        max_3d_side: 2048,
        store_dir: dir.path().join("stores"),
        labels: false,
        spread: false,
    };
    let p = Progress::default();
    let local = open(&Input::Path(json), &opts, &p).unwrap();
    let store = dir.path().join("stores/s.brs");
    let bytes = std::fs::read(&store).unwrap();
    let url = format!(
        "{}/viewer-{}/s.brs",
        http.trim_end_matches('/'),
        std::process::id()
    );
    put_file(&url, &bytes);
    let remote = open(&Input::parse(&url).unwrap(), &opts, &p).unwrap();
    assert!(matches!(remote.volume, Opened::Streamed(_)));
    assert_eq!(remote.desc, local.desc);
    assert_eq!(remote.histogram, local.histogram);
    assert!(remote.note.contains("brick store"), "{}", remote.note);
}

/// An OME-Zarr image's URL on the Range HTTP test server streams as a
/// brick source: the dims and sample type of the local image, and its
/// bricks equal the local reader's.
#[cfg(feature = "remote")]
#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP and BRICKRAY_ALLOW_HTTP=1 (scripts/test.sh sets both)"]
fn an_ome_zarr_url_streams_as_the_local_image() {
    let Some(http) = test_http() else {
        return;
    };
    let image = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/formats/ome-zarr/pycortex_s1_t1_v05.ome.zarr");
    if !image.is_dir() {
        assert!(
            !std::env::var("CI").is_ok_and(|v| v == "true"),
            "CI=true but {} is missing",
            image.display()
        );
        return eprintln!("skipping: no shared data");
    }
    let url = format!(
        "{}/viewer-zarr-{}/t1.ome.zarr",
        http.trim_end_matches('/'),
        std::process::id()
    );
    put_tree(&image, &image, &url);
    let opts = OpenOptions {
        in_core_max_bytes: 0,
        max_3d_side: 2048,
        store_dir: std::env::temp_dir(),
        labels: false,
        spread: false,
    };
    let remote = open(&Input::parse(&url).unwrap(), &opts, &Progress::default()).unwrap();
    let Opened::Streamed(src) = &remote.volume else {
        panic!("not streamed")
    };
    assert!(remote.note.contains("OME-Zarr"), "{}", remote.note);
    let d = brickray::store::BuildOptions::default();
    let range = src.layout().volume.value_range;
    let local = brickray::io::zarr::ZarrBrickSource::open(
        &image,
        &brickray::io::ReadOptions::default(),
        d.brick,
        d.apron,
        Some(range),
    )
    .unwrap();
    assert_eq!(local.layout(), src.layout());
    let (mut a, mut b) = (
        vec![0u8; local.layout().brick_bytes()],
        vec![0u8; local.layout().brick_bytes()],
    );
    let leaf = local.layout().levels - 1;
    let mut data = 0;
    for z in 0..1u32 << leaf {
        for x in 0..1u32 << leaf {
            let k = NodeKey {
                level: leaf,
                x,
                y: 0,
                z,
            };
            local.read_brick(k, &mut a).unwrap();
            src.read_brick(k, &mut b).unwrap();
            assert!(a == b, "brick {k:?}");
            data += usize::from(a.iter().any(|&v| v != a[0]));
        }
    }
    assert!(data > 0, "no brick with data compared");
}

/// A multi-channel OME-Zarr's URL on the Range HTTP test server opens with
/// every channel, read whole as the local image is (the same channels and
/// styles); too large for the in-core budget, its first channel streams.
#[cfg(feature = "remote")]
#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP and BRICKRAY_ALLOW_HTTP=1 (scripts/test.sh sets both)"]
fn a_multi_channel_ome_zarr_url_opens_with_every_channel() {
    let Some(http) = test_http() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let json = write_channels(dir.path(), 3);
    let read = brickray::io::read_channels(&json, &ReadOptions::default()).unwrap();
    let root = dir.path().join("c.ome.zarr");
    brickray::io::zarr::write_ome_zarr_channels(&root, &read.volume, &read.info).unwrap();
    let url = format!(
        "{}/viewer-channels-{}/c.ome.zarr",
        http.trim_end_matches('/'),
        std::process::id()
    );
    put_tree(&root, &root, &url);
    let p = Progress::default();
    let remote = open(&Input::parse(&url).unwrap(), &in_core(dir.path()), &p).unwrap();
    let local = open(&Input::Path(root), &in_core(dir.path()), &p).unwrap();
    let (Opened::Channels(r), Opened::Channels(l)) = (&remote.volume, &local.volume) else {
        panic!("not opened as channels: {} / {}", remote.note, local.note)
    };
    assert_eq!(whole(r), whole(l));
    assert_eq!(r.styles, l.styles);
    assert_eq!(r.data.len(), 3);
    assert!(remote.note.contains("3 channels"), "{}", remote.note);
    // No level fits a budget of one byte: every channel streams, with the
    // same styles.
    let tight = OpenOptions {
        in_core_max_bytes: 1,
        ..in_core(dir.path())
    };
    let streamed = open(&Input::parse(&url).unwrap(), &tight, &p).unwrap();
    let Opened::Channels(s) = &streamed.volume else {
        panic!("not streamed channels: {}", streamed.note)
    };
    assert!(
        matches!(s.data, ChannelData::Streamed(_)),
        "{}",
        streamed.note
    );
    assert_eq!(s.styles, l.styles);
}

/// The channels read whole (panics when they were streamed).
fn whole(c: &OpenedChannels) -> &brickray::ChannelVolume {
    match &c.data {
        ChannelData::InCore(v) => v,
        ChannelData::Streamed(_) => panic!("streamed, not read whole"),
    }
}

/// A multi-channel input too large for the in-core budget streams: a raw
/// file's channels built into one store each (reused when opened again), an
/// OME-Zarr image's channels as they are; the file's styles either way,
/// each channel's value range and a histogram of each.
#[test]
fn large_multi_channel_inputs_stream_every_channel() {
    let dir = tempfile::tempdir().unwrap();
    let json = write_channels(dir.path(), 3);
    let read = brickray::io::read_channels(&json, &ReadOptions::default()).unwrap();
    let tight = OpenOptions {
        in_core_max_bytes: 1,
        ..in_core(dir.path())
    };
    let p = Progress::default();
    let ranges: Vec<[f32; 2]> = read
        .volume
        .channels()
        .iter()
        .map(|v| v.desc().value_range)
        .collect();
    let check = |l: &Loaded| {
        let Opened::Channels(c) = &l.volume else {
            panic!("not channels: {}", l.note)
        };
        let ChannelData::Streamed(src) = &c.data else {
            panic!("not streamed: {}", l.note)
        };
        assert_eq!(src.len(), 3);
        assert_eq!(src.layout().channel_ranges(), ranges.as_slice());
        assert_eq!(c.styles, read.styles());
        assert_eq!(c.histograms.len(), 3);
        assert!(c.histograms.iter().all(|h| h.bins.iter().sum::<u64>() > 0));
        assert_eq!(l.desc.dims, [8, 6, 4]);
    };
    let l = open(&Input::Path(json.clone()), &tight, &p).unwrap();
    check(&l);
    assert!(l.note.contains("built brick stores"), "{}", l.note);
    for c in 0..3 {
        assert!(dir.path().join(format!("stores/c.c{c}.brs")).exists());
    }
    let again = open(&Input::Path(json), &tight, &p).unwrap();
    check(&again);
    assert!(again.note.contains("reused brick stores"), "{}", again.note);
    // The channel set the build recorded opens as the input did.
    let set = dir.path().join("stores/c.channels.json");
    let s = open(&Input::Path(set), &tight, &p).unwrap();
    check(&s);
    assert!(s.note.contains("channel set"), "{}", s.note);
    let root = dir.path().join("c.ome.zarr");
    brickray::io::zarr::write_ome_zarr_channels(&root, &read.volume, &read.info).unwrap();
    let z = open(&Input::Path(root), &tight, &p).unwrap();
    check(&z);
    assert!(z.note.contains("OME-Zarr"), "{}", z.note);
}

#[test]
fn procedural_volumes_open_with_a_histogram() {
    let opts = OpenOptions {
        in_core_max_bytes: 0,
        max_3d_side: 2048,
        store_dir: std::env::temp_dir(),
        labels: false,
        spread: false,
    };
    let l = open(&Input::Procedural(128), &opts, &Progress::default()).unwrap();
    assert!(matches!(l.volume, Opened::Streamed(_)));
    assert_eq!(l.desc.dims, [128; 3]);
    assert!(l.histogram.bins.iter().filter(|&&c| c > 0).count() > 10);
    let b = open(&Input::Bulb(128), &opts, &Progress::default()).unwrap();
    assert!(matches!(b.volume, Opened::Streamed(_)));
    assert_eq!(b.desc.dims, [128; 3]);
    // Air and a solid: the first bin (air) and the solid's bins are filled.
    assert!(b.histogram.bins[0] > 0);
    assert!(
        b.histogram.bins[b.histogram.bins.len() / 2..]
            .iter()
            .any(|&c| c > 0)
    );
}

/// A raw + JSON sidecar of `n` planar u16 channels of 8x6x4 (channel `c`
/// holds `c * 1000 + i % 97`) without a value range (each channel's is its
/// own).
fn write_channels(dir: &Path, n: u64) -> PathBuf {
    let voxels = 8 * 6 * 4;
    let mut bytes = Vec::new();
    for c in 0..n {
        for i in 0..voxels {
            bytes.extend_from_slice(&((c * 1000 + i % 97) as u16).to_le_bytes());
        }
    }
    std::fs::write(dir.join("c.raw"), bytes).unwrap();
    let json = dir.join("c.json");
    std::fs::write(
        &json,
        format!(
            r#"{{"dims": [8, 6, 4], "dtype": "u16", "spacing": [1, 1, 2], "file": "c.raw", "channels": {n}}}"#
        ),
    )
    .unwrap();
    json
}

fn in_core(dir: &Path) -> OpenOptions {
    OpenOptions {
        in_core_max_bytes: 1 << 20,
        max_3d_side: 2048,
        store_dir: dir.join("stores"),
        labels: false,
        spread: false,
    }
}

/// A multi-channel input opens with every channel (`read_channels`) and the
/// file's default styles; one channel keeps the single-channel path; more
/// than four shows the first four and says so.
#[test]
fn multi_channel_inputs_open_with_every_channel_and_the_files_styles() {
    let dir = tempfile::tempdir().unwrap();
    let opts = in_core(dir.path());
    let json = write_channels(dir.path(), 3);
    let l = open(&Input::Path(json.clone()), &opts, &Progress::default()).unwrap();
    let Opened::Channels(c) = &l.volume else {
        panic!("not channels: {:?}", l.volume);
    };
    let read = brickray::io::read_channels(&json, &ReadOptions::default()).unwrap();
    assert_eq!(whole(c), &read.volume);
    assert_eq!(c.styles, read.styles());
    assert_eq!(c.histograms.len(), 3);
    assert_eq!(l.desc.dims, [8, 6, 4]);
    assert_eq!(l.desc.spacing, [1.0, 1.0, 2.0]);
    assert!(l.note.contains("3 channels"), "{}", l.note);
    for h in &c.histograms {
        assert_eq!(h.bins.iter().sum::<u64>(), 8 * 6 * 4);
    }

    let one = tempfile::tempdir().unwrap();
    let json = write_channels(one.path(), 1);
    let l = open(&Input::Path(json), &opts, &Progress::default()).unwrap();
    assert!(matches!(l.volume, Opened::InCore(_)), "{:?}", l.volume);

    let five = tempfile::tempdir().unwrap();
    let json = write_channels(five.path(), 5);
    let l = open(&Input::Path(json), &opts, &Progress::default()).unwrap();
    let Opened::Channels(c) = &l.volume else {
        panic!("not channels: {:?}", l.volume);
    };
    assert_eq!(c.data.len(), 4);
    assert!(l.note.contains("has 5 channels"), "{}", l.note);
    // A label map (`--labels`) is never read as channels.
    let labels = OpenOptions {
        labels: true,
        spread: false,
        ..in_core(dir.path())
    };
    let json = write_channels(dir.path(), 2);
    let l = open(&Input::Path(json), &labels, &Progress::default()).unwrap();
    assert!(matches!(l.volume, Opened::InCore(_)), "{:?}", l.volume);
}

/// A multi-channel volume too large for one texture (or the in-core limit)
/// streams, and its note says why.
#[test]
fn a_multi_channel_volume_too_large_for_one_texture_streams() {
    let dir = tempfile::tempdir().unwrap();
    let json = write_channels(dir.path(), 2);
    for (opts, why) in [
        (
            OpenOptions {
                max_3d_side: 4,
                ..in_core(dir.path())
            },
            "3D texture limit",
        ),
        (
            OpenOptions {
                in_core_max_bytes: 500,
                ..in_core(dir.path())
            },
            "--in-core-max",
        ),
    ] {
        let l = open(&Input::Path(json.clone()), &opts, &Progress::default()).unwrap();
        let Opened::Channels(c) = &l.volume else {
            panic!("not channels: {}", l.note)
        };
        assert!(matches!(c.data, ChannelData::Streamed(_)), "{}", l.note);
        assert!(
            l.note.contains("streamed") && l.note.contains(why),
            "{}",
            l.note
        );
    }
}
