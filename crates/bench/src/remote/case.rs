//! One case of the `remote` suite: a source opened over a transport, driven
//! along the camera path, and what it measured.

use super::*;

/// A host's frame period (60 Hz).
const FRAME: Duration = Duration::from_micros(16_667);
/// Frames of the slow orbit and of the slow motion after the close-up.
const ORBIT: usize = 15;
const MOVE: usize = 15;
/// Most frames a view is held waiting for convergence.
const MAX_HOLD: usize = 1800;

/// Requests and bytes fetched so far.
pub(super) type FetchedFn = Box<dyn Fn() -> (u64, u64)>;

/// A source opened for one case, with what counts its traffic.
pub(super) struct Opened {
    source: Arc<dyn BrickSource>,
    fetched: FetchedFn,
    /// A store's payload bytes per node (for the drawn bricks' bytes).
    store: Option<Arc<Store>>,
    /// Set-up so far (opening), in seconds.
    open_s: f64,
}

/// How a case reads the store over the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Variant {
    /// Bricks in batches (the default).
    Batched,
    /// One request per brick.
    Unbatched,
    /// Through a disk cache, empty.
    CacheCold,
    /// Through the disk cache the cold case filled.
    CacheWarm,
    /// From S3 (moto), batched.
    S3,
    /// Batched, asking for the next level ahead ([`Lookahead::Remote`]).
    Lookahead,
}

impl Variant {
    pub(super) fn name(self) -> &'static str {
        match self {
            Variant::Batched => "batched",
            Variant::Unbatched => "unbatched",
            Variant::CacheCold => "cache_cold",
            Variant::CacheWarm => "cache_warm",
            Variant::S3 => "s3",
            Variant::Lookahead => "lookahead",
        }
    }
}

pub(super) fn open(
    src: &str,
    base: Option<&str>,
    (store_path, zarr): (&Path, &Path),
    opts: &RemoteOptions,
    variant: Variant,
    cache: &DiskCacheConfig,
) -> Result<Opened, String> {
    let t = Instant::now();
    let (d_brick, d_apron) = {
        let d = BuildOptions::default();
        (d.brick, d.apron)
    };
    let read = brickray_io::ReadOptions::default();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let (source, fetched, store): (Arc<dyn BrickSource>, FetchedFn, _) = match (src, base) {
        ("brs", None) => {
            let file = std::fs::File::open(store_path).map_err(|x| e(&x))?;
            let counting = Arc::new(Counting::new(file));
            let store =
                Arc::new(Store::open_with(counting.clone(), store_path).map_err(|x| e(&x))?);
            let c = counting.clone();
            (store.clone(), Box::new(move || c.get()), Some(store))
        }
        ("brs", Some(base)) if matches!(variant, Variant::CacheCold | Variant::CacheWarm) => {
            let url = format!("{base}/mri.brs");
            let reader = RemoteRangeReader::open(&url, opts).map_err(|x| e(&x))?;
            let id = format!(
                "{url}\n{}\n{}",
                reader.etag().unwrap_or(""),
                reader.object_len()
            );
            let cached = Arc::new(DiskCached::new(reader, &id, cache).map_err(|x| e(&x))?);
            let store = Arc::new(Store::open_with(cached.clone(), &url).map_err(|x| e(&x))?);
            let fetched = Box::new(move || {
                let f = cached.inner().fetched();
                (f.requests, f.bytes)
            });
            (store.clone(), fetched, Some(store))
        }
        ("brs", Some(base)) => {
            let url = format!("{base}/mri.brs");
            let reader = Arc::new(RemoteRangeReader::open(&url, opts).map_err(|x| e(&x))?);
            let store = Arc::new(Store::open_with(reader.clone(), &url).map_err(|x| e(&x))?);
            let source: Arc<dyn BrickSource> = if variant == Variant::Unbatched {
                Arc::new(Unbatched(store.clone()))
            } else {
                store.clone()
            };
            let r = reader.clone();
            let fetched = Box::new(move || {
                let f = r.fetched();
                (f.requests, f.bytes)
            });
            (source, fetched, Some(store))
        }
        ("zarr", None) => {
            let z =
                ZarrBrickSource::open(zarr, &read, d_brick, d_apron, None).map_err(|x| e(&x))?;
            (Arc::new(z), Box::new(|| (0, 0)), None)
        }
        ("zarr", Some(base)) if matches!(variant, Variant::CacheCold | Variant::CacheWarm) => {
            let url = format!("{base}/mri.ome.zarr");
            let objects = RemoteObjects::open(&url, opts).map_err(|x| e(&x))?;
            let cached = Arc::new(DiskCachedObjects::for_image(objects, cache).map_err(|x| e(&x))?);
            let z = ZarrBrickSource::open_objects(cached.clone(), &read, d_brick, d_apron, None)
                .map_err(|x| e(&x))?;
            let fetched = Box::new(move || {
                let f = cached.inner().fetched();
                (f.requests, f.bytes)
            });
            (Arc::new(z), fetched, None)
        }
        ("zarr", Some(base)) => {
            let url = format!("{base}/mri.ome.zarr");
            let objects = Arc::new(RemoteObjects::open(&url, opts).map_err(|x| e(&x))?);
            let z = ZarrBrickSource::open_objects(objects.clone(), &read, d_brick, d_apron, None)
                .map_err(|x| e(&x))?;
            let o = objects.clone();
            let fetched = Box::new(move || {
                let f = o.fetched();
                (f.requests, f.bytes)
            });
            (Arc::new(z), fetched, None)
        }
        _ => return Err(format!("unknown source {src}")),
    };
    Ok(Opened {
        source,
        fetched,
        store,
        open_s: t.elapsed().as_secs_f64(),
    })
}

/// What one case measured.
#[derive(Debug, Clone)]
pub(super) struct CaseResult {
    pub(super) first_image_s: f64,
    pub(super) converged_s: f64,
    pub(super) converged_frames: usize,
    pub(super) after_jump: Option<usize>,
    /// Requests and bytes fetched over the whole case.
    pub(super) fetched: (u64, u64),
    /// Bytes fetched / payload bytes of the bricks the cuts drew (a store).
    pub(super) bytes_ratio: Option<f64>,
    pub(super) requests_per_brick: f64,
    /// Requests cancelled: queued, in flight.
    pub(super) cancelled: [u64; 2],
    pub(super) median_ms: f64,
    pub(super) p99_ms: f64,
    pub(super) max_ms: f64,
    /// p99 over median of the render thread's part of the frames (the
    /// frame less the ray-cast pass), where measured.
    pub(super) host_p99_over_median: Option<f64>,
}

pub(super) fn case(
    gpu: &GpuContext,
    run: &Runner<'_>,
    opened: Opened,
    threads: usize,
    lookahead: Lookahead,
    (raycast, fades, background): (bool, bool, bool),
) -> Result<CaseResult, String> {
    let layout = opened.source.layout().clone();
    let d = layout.volume.clone();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let tf = TfModel::preset(TfPreset::Mri, d.value_range)
        .to_table(256)
        .map_err(|e| e.to_string())?;
    let settings = RenderSettings::default();
    let start = Instant::now();
    let options = brickray_render::RendererOptions {
        background_planning: background,
        ..Default::default()
    };
    let mut r = VolumeRenderer::with_options(&gpu.device, brickray_harness::target_desc(), options)
        .map_err(|e| e.to_string())?;
    r.set_volume_source(
        &gpu.device,
        &gpu.queue,
        opened.source.clone(),
        OutOfCoreConfig {
            loader_threads: threads,
            lookahead,
            fade: OutOfCoreConfig::default().fade.filter(|_| fades),
            ..OutOfCoreConfig::default()
        },
    )
    .map_err(|e| e.to_string())?;
    r.set_transfer_function(&gpu.device, &gpu.queue, &tf)
        .map_err(|e| e.to_string())?;
    // As a host does at set-up: no frame pays for compiling the pipelines.
    r.warm_up(&gpu.device, &[settings])
        .map_err(|e| e.to_string())?;
    let c = frame.center();
    // The `ooc` suite's path (the frame's longest side is 1).
    let close = c + Vec3::new(-0.25, 0.2, -0.35);
    let radius = 2.0;
    let start_cam = Camera::orbit(c, radius, 0.5, 0.3);
    let mut walk = Walk {
        run,
        frame,
        settings,
        drawn: HashSet::new(),
        streaming_ms: Vec::new(),
        host_ms: Vec::new(),
        frames: 0,
        raycast,
    };
    // The first frame: the root (preloaded at set-up) covers every pixel.
    let first = walk.step(&mut r, start_cam)?;
    let first_image_s = opened.open_s + start.elapsed().as_secs_f64();
    let mut converged = first.then_some(1);
    let mut frames = 1;
    while converged.is_none() && frames < MAX_HOLD {
        frames += 1;
        if walk.step(&mut r, start_cam)? {
            converged = Some(frames);
        }
    }
    let converged_s = opened.open_s + start.elapsed().as_secs_f64();
    for i in 0..ORBIT {
        walk.step(&mut r, Camera::orbit(c, radius, 0.5 + 0.01 * i as f32, 0.3))?;
    }
    let close_cam = Camera::orbit(close, 0.2 * radius, 3.3, -0.2);
    let mut after_jump = None;
    for i in 1..=MAX_HOLD {
        if walk.step(&mut r, close_cam)? {
            after_jump = Some(i);
            break;
        }
    }
    for i in 0..MOVE {
        walk.step(
            &mut r,
            Camera::orbit(close, 0.2 * radius, 3.3 + 0.005 * (i + 1) as f32, -0.2),
        )?;
    }
    let fetched = (opened.fetched)();
    let loaded = r
        .streamed_volume()
        .ok_or("not out of core")?
        .inspect(|s| s.manager().loader().loaded_total());
    let bytes_ratio = opened.store.as_ref().map(|s| {
        let drawn: u64 = walk
            .drawn
            .iter()
            .filter_map(|&k| s.record(k).ok())
            .map(|n| n.payload_len as u64)
            .sum();
        fetched.1 as f64 / drawn.max(1) as f64
    });
    let ms = if walk.streaming_ms.is_empty() {
        vec![0.0]
    } else {
        walk.streaming_ms
    };
    Ok(CaseResult {
        first_image_s,
        converged_s,
        converged_frames: converged.unwrap_or(frames),
        after_jump,
        fetched,
        bytes_ratio,
        requests_per_brick: fetched.0 as f64 / loaded.max(1) as f64,
        cancelled: r.stats().out_of_core.map_or([0, 0], |s| s.cache.cancelled),
        median_ms: median(&ms),
        p99_ms: quantile(&ms, 0.99),
        max_ms: ms.iter().copied().fold(0.0, f64::max),
        host_p99_over_median: (!walk.host_ms.is_empty())
            .then(|| quantile(&walk.host_ms, 0.99) / median(&walk.host_ms).max(1e-9)),
    })
}

/// The camera path's frames, paced at 60 Hz.
pub(super) struct Walk<'a, 'g> {
    run: &'a Runner<'g>,
    frame: VolumeFrame,
    settings: RenderSettings,
    /// Every brick that reached the GPU pool (drawn by some frame's cut,
    /// as a fallback or as the floor).
    drawn: HashSet<NodeKey>,
    /// Planned frames' wall time while bricks were in flight, the first
    /// frame excepted.
    streaming_ms: Vec<f64>,
    /// The host thread's part of the same frames (`prepare`, recording,
    /// submitting; ray-cast frames only).
    host_ms: Vec<f64>,
    /// Frames planned.
    frames: usize,
    /// Ray cast every frame too (`--raycast`), not only plan it.
    raycast: bool,
}

impl Walk<'_, '_> {
    /// Plans one frame; returns whether the view has converged.
    fn step(&mut self, r: &mut VolumeRenderer, camera: Camera) -> Result<bool, String> {
        let t = Instant::now();
        let mut host_ms = None;
        if self.raycast {
            host_ms = Some(
                self.run
                    .frame(r, camera, self.frame, self.settings, false)?
                    .host_ms,
            );
        } else {
            self.run.plan(r, camera, self.frame, self.settings)?;
        }
        let took = t.elapsed();
        let s = r.stats().out_of_core.ok_or("not out of core")?;
        // The first frame allocates the pool (set-up, counted in the first
        // image's time), the others are the host's frames.
        if self.frames > 0 && (s.cache.requests_in_flight > 0 || !s.converged) {
            self.streaming_ms.push(took.as_secs_f64() * 1e3);
            self.host_ms.extend(host_ms);
        }
        self.frames += 1;
        let v = r.streamed_volume().ok_or("not out of core")?;
        v.inspect(|st| self.drawn.extend(st.pool().resident().map(|(k, _)| k)));
        std::thread::sleep(FRAME.saturating_sub(t.elapsed()));
        Ok(s.converged)
    }
}

/// A store read one brick per request (the loader before batches).
pub(super) struct Unbatched(Arc<Store>);

impl BrickSource for Unbatched {
    fn layout(&self) -> &OctreeLayout {
        self.0.layout()
    }
    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        self.0.node(key)
    }
    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        self.0.read_brick(key, out)
    }
}

/// A local file that counts its reads (each range one request) and bytes.
#[derive(Debug)]
pub(super) struct Counting {
    file: std::fs::File,
    requests: AtomicU64,
    bytes: AtomicU64,
}

impl Counting {
    fn new(file: std::fs::File) -> Counting {
        Counting {
            file,
            requests: AtomicU64::new(0),
            bytes: AtomicU64::new(0),
        }
    }

    fn get(&self) -> (u64, u64) {
        (
            self.requests.load(Ordering::Relaxed),
            self.bytes.load(Ordering::Relaxed),
        )
    }
}

impl RangeReader for Counting {
    fn len(&self) -> std::io::Result<u64> {
        self.file.len()
    }
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
        self.requests.fetch_add(1, Ordering::Relaxed);
        self.bytes.fetch_add(buf.len() as u64, Ordering::Relaxed);
        RangeReader::read_exact_at(&self.file, buf, offset)
    }
    fn read_ranges(&self, ranges: &mut [RangeRead<'_>]) -> std::io::Result<()> {
        for r in ranges {
            self.read_exact_at(r.buf, r.offset)?;
        }
        Ok(())
    }
}
