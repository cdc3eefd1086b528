//! The `remote` suite: streaming a volume over HTTP with added round-trip
//! time, against the same volume read from the local disk (docs/remote.md).
//!
//! The shared T1 MRI (pycortex S1, u8 256^3) as a brick store (`.brs`, built
//! here) and as the shared OME-Zarr 0.5 image of it, served by the Range
//! HTTP test server (`scripts/test-servers/range_http.py`) behind the
//! fault proxy (`fault_proxy.py --cycle ok --delay MS`) adding `--delays`
//! milliseconds (0, 20, 80) to every request; both started here and stopped
//! at the end. Each case opens the source, sets it on a renderer (default
//! out-of-core configuration, `--threads` loader threads) and walks the
//! camera path of the `ooc` suite's part (c) at `--size` px (512): the start
//! view held until it converges, a slow orbit, a jump to a close-up held
//! until it converges, slow motion. Frames are planned, not ray cast
//! (`prepare` with its uploads, then a submission: the render thread's whole
//! share of a frame; lavapipe takes seconds to ray cast 512^2), paced at
//! 60 Hz like a host's frame loop.
//!
//! Per case: the time to the first complete image (set-up, which reads the
//! metadata and the root brick, plus the first frame: every pixel is drawn
//! from the root or finer from then on); time and frames to the start
//! view's convergence; frames to converge after the jump; requests and bytes
//! fetched (a `.brs`: against the payload bytes of the bricks the cuts drew,
//! every brick that reached the GPU pool); requests per brick loaded; median
//! and p99 of the planned frames' wall time while bricks were in flight.
//! Both sources at the largest delay run again with the lookahead
//! (`Lookahead::Remote`): what asking for the next level ahead saves. The
//! store at the largest delay runs a second time with batching off (one
//! request per brick, as the loader read before batches): the requests
//! batching saves; and both sources twice through a disk cache
//! (`DiskCached`, `DiskCachedObjects`, empty each round): its first visit
//! fills the cache, its second reads from it.
//!
//! With `--raycast` every frame is also ray cast (`prepare`, the ray cast,
//! submit and wait: a host's whole frame), so the frame times include what
//! the device does; use a smaller `--size` on a software device.
//!
//! Every case runs `--rounds` times (3), the cases in turn each round; a
//! case's row is its round of median convergence time, with the median
//! time to the first image.
//!
//! Where moto is installed (`python3 -m pip install 'moto[server]'`, as
//! scripts/test.sh does) the same objects are also read from an S3 bucket
//! on it, behind proxies with the same delays.
//!
//! `cargo run --release -p brickray-bench -- remote [--size PX] [--delays
//! 0,20,80] [--threads N] [--rounds N] [--gap-kib K] [--raycast]` (needs
//! ../shared/data and python3).

mod case;
mod servers;

use crate::runner::{Runner, median, quantile, round2};
use brickray_core::tf::{TfModel, TfPreset};
use brickray_core::{
    BrickError, BrickSource, Camera, NodeInfo, NodeKey, OctreeLayout, RangeRead, RangeReader,
    RenderSettings, VolumeFrame,
};
use brickray_harness::GpuContext;
use brickray_io::zarr::ZarrBrickSource;
use brickray_remote::{
    DiskCacheConfig, DiskCached, DiskCachedObjects, RemoteObjects, RemoteOptions, RemoteRangeReader,
};
use brickray_render::{Lookahead, OutOfCoreConfig, VolumeRenderer};
use brickray_store::{BuildOptions, Store};
use case::{CaseResult, Variant, case, open};
use glam::Vec3;
use serde::Serialize;
use servers::{Server, copy_dir, create_bucket, files, s3_options, start_moto, start_proxies};
use std::collections::HashSet;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// An added delay in ms.
fn delay(s: &str) -> Result<u32, String> {
    s.trim().parse().map_err(|_| format!("bad delay {s:?}"))
}

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels of the planned frames.
    #[arg(long, default_value_t = 512, value_parser = crate::image_side)]
    size: u32,
    /// Added delays in ms, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "0,20,80", value_parser = delay)]
    delays: Vec<u32>,
    /// Loader threads.
    #[arg(long, default_value_t = 8, value_parser = crate::at_least_one::<usize>)]
    threads: usize,
    /// Ranges this close (KiB) are fetched as one request.
    #[arg(long, default_value_t = brickray_remote::DEFAULT_COALESCE_GAP >> 10)]
    gap_kib: u64,
    /// Rounds of every case (each row is the median round).
    #[arg(long, default_value_t = 3, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Ray cast every frame too (whole frames; default: planned only).
    #[arg(long)]
    raycast: bool,
    /// Draw without fades between levels (`OutOfCoreConfig::fade` None): a
    /// fading brick samples two levels, which is ray-cast time.
    #[arg(long)]
    no_fades: bool,
    /// Plan on a worker (`RendererOptions::background_planning`, as the
    /// viewer does) instead of in `prepare`.
    #[arg(long)]
    background: bool,
}

/// One case: a source over a transport, its median round.
#[derive(Debug, Serialize)]
pub(crate) struct CaseRow {
    /// brs (the store) or zarr (the OME-Zarr image).
    source: &'static str,
    /// local, http or s3, with its variant.
    transport: String,
    /// Added round-trip delay, ms (null: local).
    delay_ms: Option<u32>,
    /// batched, unbatched, cache_cold, cache_warm, s3, lookahead.
    variant: &'static str,
    first_image_s: f64,
    converged_s: f64,
    converged_frames: usize,
    /// Converged time over the local file's.
    converged_ratio_vs_local: f64,
    frames_after_jump: Option<usize>,
    requests: u64,
    mib_fetched: f64,
    /// Bytes fetched over the bytes of the bricks drawn (stores).
    bytes_ratio: Option<f64>,
    requests_per_brick: f64,
    cancelled_queued: u64,
    cancelled_in_flight: u64,
    /// Frame times while streaming, ms.
    median_ms: f64,
    p99_ms: f64,
    p99_over_median: f64,
    slowest_frame_ms: f64,
    /// With `--raycast`: the same for the render thread's part of each
    /// frame (`prepare`, recording and submitting, before the wait for the
    /// GPU), null otherwise.
    p99_over_median_host: Option<f64>,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct RemoteResult {
    size: u32,
    threads: usize,
    rounds: usize,
    /// Whether frames were ray cast, drawn with fades, planned on a worker.
    raycast: bool,
    fades: bool,
    background: bool,
    cases: Vec<CaseRow>,
    /// The store over HTTP at the largest delay: its delay and figures.
    worst_delay_ms: Option<u32>,
    first_image_s: Option<f64>,
    converged_ratio_vs_local: Option<f64>,
    bytes_ratio_vs_cut: Option<f64>,
    requests_per_brick: Option<f64>,
    p99_over_median_streaming: Option<f64>,
    p99_over_median_streaming_host: Option<f64>,
    slowest_streaming_frame_ms: Option<f64>,
    /// The same at 80 ms, when run (the figures the issue names).
    first_image_s_80ms: Option<f64>,
    converged_ratio_80ms_vs_local: Option<f64>,
    /// At the largest delay: requests batching saves (share), and unbatched
    /// over batched convergence time.
    requests_saved_by_batching: Option<f64>,
    converged_ratio_unbatched_vs_batched: Option<f64>,
    /// At the largest delay: without over with lookahead.
    brs_converged_ratio_no_lookahead_vs_lookahead: Option<f64>,
    zarr_converged_ratio_no_lookahead_vs_lookahead: Option<f64>,
    /// A second visit through the disk cache: its convergence time over
    /// the first visit's, and its requests (store, OME-Zarr).
    disk_cache_second_visit_converged_ratio: Option<f64>,
    disk_cache_second_visit_requests: Option<u64>,
    zarr_disk_cache_second_visit_converged_ratio: Option<f64>,
    zarr_disk_cache_second_visit_requests: Option<u64>,
}

pub(crate) fn run(args: &Args) -> Result<RemoteResult, String> {
    let (size, threads, rounds, raycast, gap_kib) = (
        args.size,
        args.threads,
        args.rounds,
        args.raycast,
        args.gap_kib,
    );
    let delays = &args.delays;
    let shared = brickray_harness::shared_data_dir()
        .ok_or("the remote suite needs ../shared/data (the shared MRI)")?;
    let raw = shared.join("pycortex_s1_t1_mri/pycortex_s1_t1_mri.json");
    let zarr = shared.join("formats/ome-zarr/pycortex_s1_t1_v05.ome.zarr");
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let root = dir.path().join("http");
    std::fs::create_dir_all(&root).map_err(|e| e.to_string())?;
    let store_path = root.join("mri.brs");
    let vol = brickray_io::read_volume(&raw).map_err(|e| e.to_string())?;
    let mut reader = brickray_io::MemoryReader::new(vol, "memory");
    brickray_store::build(&mut reader, &store_path, &BuildOptions::default())
        .map_err(|e| e.to_string())?;
    copy_dir(&zarr, &root.join("mri.ome.zarr"))?;
    let scripts = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/test-servers");
    let server = Server::start(
        dir.path(),
        "http",
        &scripts.join("range_http.py"),
        &["--root", &root.to_string_lossy()],
    )?;
    let upstream = format!("http://127.0.0.1:{}", server.port);
    let proxies = start_proxies(dir.path(), &scripts, "http", &upstream, delays)?;
    // S3 (moto) when it is installed: the same objects in a bucket, behind
    // proxies with the same delays.
    let moto = start_moto()?;
    let mut s3_proxies = Vec::new();
    if let Some(m) = &moto {
        let endpoint = format!("http://127.0.0.1:{}", m.port);
        create_bucket(m.port, "bench")?;
        let direct = s3_options(&endpoint, gap_kib);
        let put = |key: &str, file: &Path| {
            let bytes = std::fs::read(file).map_err(|e| format!("{}: {e}", file.display()))?;
            brickray_remote::put_object(&format!("s3://bench/{key}"), &direct, bytes)
                .map_err(|e| e.to_string())
        };
        put("mri.brs", &store_path)?;
        for f in files(&root.join("mri.ome.zarr"))? {
            let rel = f.strip_prefix(&root).map_err(|e| e.to_string())?;
            put(&rel.to_string_lossy(), &f)?;
        }
        s3_proxies = start_proxies(dir.path(), &scripts, "s3", &endpoint, delays)?;
    }
    println!(
        "pycortex S1 T1 MRI (u8 256^3): a .brs store ({:.1} MiB) and the shared OME-Zarr 0.5 image, over a Range HTTP server with added delay; {size}x{size} frames {} at 60 Hz at most, {threads} loader threads",
        std::fs::metadata(&store_path).map_or(0.0, |m| m.len() as f64 / (1 << 20) as f64),
        if raycast { "ray cast" } else { "planned" },
    );
    println!(
        "\n| source | transport | first image s | converged s (frames) | after the jump (frames) | requests | MiB fetched | fetched / drawn bricks | requests per brick | cancelled queued / in flight | p99 / median ms streaming | slowest frame ms |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let opts = RemoteOptions {
        allow_http: true,
        coalesce_gap: gap_kib << 10,
        ..RemoteOptions::default()
    };
    let mut cases: Vec<(&'static str, String, Option<u32>, Variant)> = Vec::new();
    for src in ["brs", "zarr"] {
        cases.push((src, "local".into(), None, Variant::Batched));
        for &d in delays {
            cases.push((src, format!("http +{d} ms"), Some(d), Variant::Batched));
        }
        if moto.is_some() {
            for &d in delays {
                cases.push((src, format!("s3 +{d} ms"), Some(d), Variant::S3));
            }
        }
    }
    if let Some(&worst) = delays.iter().max() {
        for src in ["brs", "zarr"] {
            cases.push((
                src,
                format!("http +{worst} ms, lookahead"),
                Some(worst),
                Variant::Lookahead,
            ));
        }
        for (src, variant, what) in [
            ("brs", Variant::Unbatched, "unbatched"),
            ("brs", Variant::CacheCold, "disk cache, first visit"),
            ("brs", Variant::CacheWarm, "disk cache, second visit"),
            ("zarr", Variant::CacheCold, "disk cache, first visit"),
            ("zarr", Variant::CacheWarm, "disk cache, second visit"),
        ] {
            cases.push((
                src,
                format!("http +{worst} ms, {what}"),
                Some(worst),
                variant,
            ));
        }
    }
    let run = Runner::new(&gpu, size)?;
    // Rounds of every case in turn (this machine's speed drifts): each
    // case's row is its median round.
    let mut rounds_of: Vec<Vec<CaseResult>> = cases.iter().map(|_| Vec::new()).collect();
    for round in 0..rounds {
        // A fresh disk cache each round: its first visit fills it.
        let cache = DiskCacheConfig {
            dir: dir.path().join(format!("cache{round}")),
            max_bytes: 1 << 30,
        };
        for ((src, _, delay, variant), done) in cases.iter().zip(&mut rounds_of) {
            let via = if *variant == Variant::S3 {
                &s3_proxies
            } else {
                &proxies
            };
            let port = |d: u32| via.iter().find(|p| p.0 == d).map_or(0, |p| p.1.port);
            let (base, case_opts) = match delay {
                None => (None, opts.clone()),
                Some(d) if *variant == Variant::S3 => (
                    Some("s3://bench".to_string()),
                    s3_options(&format!("http://127.0.0.1:{}", port(*d)), gap_kib),
                ),
                Some(d) => (Some(format!("http://127.0.0.1:{}", port(*d))), opts.clone()),
            };
            let paths = (store_path.as_path(), zarr.as_path());
            let opened = open(src, base.as_deref(), paths, &case_opts, *variant, &cache)?;
            let lookahead = if *variant == Variant::Lookahead {
                Lookahead::Remote
            } else {
                Lookahead::default()
            };
            done.push(case(
                &gpu,
                &run,
                opened,
                threads,
                lookahead,
                (raycast, !args.no_fades, args.background),
            )?);
        }
    }
    let mut results = Vec::new();
    for ((src, transport, delay, variant), mut done) in cases.into_iter().zip(rounds_of) {
        let first: Vec<f64> = done.iter().map(|r| r.first_image_s).collect();
        let converged: Vec<String> = done
            .iter()
            .map(|r| format!("{:.2}", r.converged_s))
            .collect();
        done.sort_by(|a, b| a.converged_s.total_cmp(&b.converged_s));
        let mut r = done.swap_remove(done.len() / 2);
        r.first_image_s = median(&first);
        println!(
            "| {src} | {transport} | {:.2} | {:.2} ({}; rounds {}) | {} | {} | {:.2} | {} | {:.2} | {} / {} | {:.2} / {:.2} = {:.2} | {:.1} |",
            r.first_image_s,
            r.converged_s,
            r.converged_frames,
            converged.join(", "),
            r.after_jump
                .map_or("not converged".into(), |f| f.to_string()),
            r.fetched.0,
            r.fetched.1 as f64 / (1 << 20) as f64,
            r.bytes_ratio.map_or("-".into(), |x| format!("{x:.2}")),
            r.requests_per_brick,
            r.cancelled[0],
            r.cancelled[1],
            r.p99_ms,
            r.median_ms,
            r.p99_ms / r.median_ms.max(1e-9),
            r.max_ms,
        );
        results.push((src, delay, variant, r));
    }
    drop(proxies);
    drop(s3_proxies);
    drop(moto);
    drop(server);
    let find = |src: &str, delay: Option<u32>, variant: Variant| {
        results
            .iter()
            .find(|r| r.0 == src && r.1 == delay && r.2 == variant)
            .map(|r| &r.3)
    };
    let ratio = |a: &CaseResult, b: &CaseResult| round2(a.converged_s / b.converged_s.max(1e-9));
    let mut rows = Vec::new();
    for (src, delay, variant, r) in &results {
        let local = find(src, None, Variant::Batched).ok_or("no local case")?;
        rows.push(CaseRow {
            source: src,
            transport: cases_transport(*delay, *variant),
            delay_ms: *delay,
            variant: variant.name(),
            first_image_s: round2(r.first_image_s),
            converged_s: round2(r.converged_s),
            converged_frames: r.converged_frames,
            converged_ratio_vs_local: ratio(r, local),
            frames_after_jump: r.after_jump,
            requests: r.fetched.0,
            mib_fetched: round2(r.fetched.1 as f64 / (1 << 20) as f64),
            bytes_ratio: r.bytes_ratio.map(round2),
            requests_per_brick: round2(r.requests_per_brick),
            cancelled_queued: r.cancelled[0],
            cancelled_in_flight: r.cancelled[1],
            median_ms: round2(r.median_ms),
            p99_ms: round2(r.p99_ms),
            p99_over_median: round2(r.p99_ms / r.median_ms.max(1e-9)),
            slowest_frame_ms: round2(r.max_ms),
            p99_over_median_host: r.host_p99_over_median.map(round2),
        });
    }
    let worst = delays.iter().max().copied();
    let at = |src, variant| worst.and_then(|d| find(src, Some(d), variant));
    let store_local = find("brs", None, Variant::Batched);
    // The store at the largest delay (80 ms by default).
    let store = at("brs", Variant::Batched);
    let at_80 = find("brs", Some(80), Variant::Batched);
    let lookahead = |src| {
        at(src, Variant::Batched)
            .zip(at(src, Variant::Lookahead))
            .map(|(without, with)| ratio(without, with))
    };
    let cache = |src| at(src, Variant::CacheCold).zip(at(src, Variant::CacheWarm));
    Ok(RemoteResult {
        size,
        threads,
        rounds,
        raycast,
        fades: !args.no_fades,
        background: args.background,
        cases: rows,
        worst_delay_ms: worst,
        first_image_s: store.map(|r| round2(r.first_image_s)),
        converged_ratio_vs_local: store.zip(store_local).map(|(r, l)| ratio(r, l)),
        bytes_ratio_vs_cut: store.and_then(|r| r.bytes_ratio.map(round2)),
        requests_per_brick: store.map(|r| round2(r.requests_per_brick)),
        p99_over_median_streaming: store.map(|r| round2(r.p99_ms / r.median_ms.max(1e-9))),
        p99_over_median_streaming_host: store.and_then(|r| r.host_p99_over_median.map(round2)),
        slowest_streaming_frame_ms: store.map(|r| round2(r.max_ms)),
        first_image_s_80ms: at_80.map(|r| round2(r.first_image_s)),
        converged_ratio_80ms_vs_local: at_80.zip(store_local).map(|(r, l)| ratio(r, l)),
        requests_saved_by_batching: store
            .zip(at("brs", Variant::Unbatched))
            .map(|(b, u)| round2(1.0 - b.fetched.0 as f64 / u.fetched.0.max(1) as f64)),
        converged_ratio_unbatched_vs_batched: store
            .zip(at("brs", Variant::Unbatched))
            .map(|(b, u)| ratio(u, b)),
        brs_converged_ratio_no_lookahead_vs_lookahead: lookahead("brs"),
        zarr_converged_ratio_no_lookahead_vs_lookahead: lookahead("zarr"),
        disk_cache_second_visit_converged_ratio: cache("brs").map(|(c, w)| ratio(w, c)),
        disk_cache_second_visit_requests: cache("brs").map(|(_, w)| w.fetched.0),
        zarr_disk_cache_second_visit_converged_ratio: cache("zarr").map(|(c, w)| ratio(w, c)),
        zarr_disk_cache_second_visit_requests: cache("zarr").map(|(_, w)| w.fetched.0),
    })
}

/// How a case reached its source, for its row.
fn cases_transport(delay: Option<u32>, variant: Variant) -> String {
    match (delay, variant) {
        (None, _) => "local".into(),
        (Some(d), Variant::S3) => format!("s3 +{d} ms"),
        (Some(d), _) => format!("http +{d} ms"),
    }
}
