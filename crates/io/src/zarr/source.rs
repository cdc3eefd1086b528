//! The OME-Zarr image served as a `BrickSource`: octree bricks assembled from
//! the chunks on demand, without a store (see [`ZarrBrickSource`]).

use super::*;

/// Most voxels of a pyramid level one brick of a [`ZarrBrickSource`] reads
/// (its footprint, box-filtered down to the brick).
pub const MAX_BRICK_READ: u64 = 1 << 30;

/// An OME-Zarr image served as a brick octree, without building a store.
///
/// The octree is the one a store built from the finest level would have
/// ([`OctreeLayout::new`] with the given brick size and apron). A brick of
/// octree level `l` (`2^s` finest voxels per voxel, `s = levels - 1 - l`) is
/// read from the coarsest pyramid level whose voxels are no larger than that
/// on any axis (its own scale transform says how much larger than the finest
/// they are, rounded to a power of two), and box-filtered by the remaining
/// factor per axis: a file whose pyramid halves only x and y (as
/// ome-zarr-py's does) is filtered along z only. An image whose pyramid
/// would make one brick read more than [`MAX_BRICK_READ`] voxels is refused
/// at open ([`IoError::Unsupported`]). Aprons come from the
/// neighbouring chunks, clamped at the volume's faces, as in a built store.
/// Node min/max are those of the brick's footprint, computed on first ask
/// and kept.
pub struct ZarrBrickSource {
    zarr: OmeZarr,
    c: u64,
    t: u64,
    layout: OctreeLayout,
    conv: SampleConverter,
    /// Per octree level: the pyramid level read and the remaining factor per axis.
    plan: Vec<(usize, [u64; 3])>,
    nodes: Mutex<HashMap<NodeKey, NodeInfo>>,
}

impl std::fmt::Debug for ZarrBrickSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZarrBrickSource")
            .field("root", &self.zarr.root)
            .field("layout", &self.layout)
            .field("plan", &self.plan)
            .finish()
    }
}

impl ZarrBrickSource {
    /// Opens `root` (channel and time point from `opts`; its level is ignored:
    /// every level is used) as an octree of `brick`-voxel bricks with `apron`
    /// voxels of apron. `value_range`: the finest level's range if known (a
    /// store built from the same data declares it), else one scan of the
    /// finest level finds it.
    pub fn open(
        root: &Path,
        opts: &ReadOptions,
        brick: u32,
        apron: u32,
        value_range: Option<[f32; 2]>,
    ) -> Result<ZarrBrickSource, IoError> {
        check_brick(root, brick, apron)?;
        let zarr = OmeZarr::open(root)?;
        ZarrBrickSource::with(zarr, opts, brick, apron, value_range)
    }

    /// Opens the image whose objects `reader` reads by key (an OME-Zarr
    /// image over HTTP or in a bucket; see [`ZarrBrickSource::open`]). Set-up
    /// reads the metadata and, without a `value_range`, the coarsest level
    /// (its range stands for the image's, which a mean pyramid's coarser
    /// levels lie within; a warning says so), or the finest level where the
    /// sample type's conversion depends on the range (32-bit integers).
    /// A missing object (404, or S3's 403) is a missing chunk: the fill
    /// value.
    pub fn open_objects(
        reader: Arc<dyn ObjectReader>,
        opts: &ReadOptions,
        brick: u32,
        apron: u32,
        value_range: Option<[f32; 2]>,
    ) -> Result<ZarrBrickSource, IoError> {
        let root = PathBuf::from(reader.location());
        check_brick(&root, brick, apron)?;
        let mut zarr = OmeZarr::open_objects(reader)?;
        let value_range = match value_range {
            Some(r) => Some(r),
            None if SampleConverter::needs_range(zarr.src, 1.0, 0.0) => None,
            None => {
                let (_, c, t) = zarr.check_choice(&ReadOptions {
                    level: None,
                    ..opts.clone()
                })?;
                let coarsest = zarr.levels.len() - 1;
                let [a, b] = scan(&zarr, coarsest, c, t)?;
                if coarsest > 0 {
                    zarr.warnings.push(format!(
                        "value range {a}..{b} from the coarsest level ({}), not a scan of \
                         the finest",
                        zarr.levels[coarsest].path
                    ));
                }
                Some([a as f32, b as f32])
            }
        };
        ZarrBrickSource::with(zarr, opts, brick, apron, value_range)
    }

    /// The channels of the image at `root` streamed together as one
    /// [`ChannelSource`](brickray_core::ChannelSource) (each channel a
    /// source of its own, read once per brick; every channel, at most
    /// [`MAX_CHANNELS`](brickray_core::MAX_CHANNELS), or those
    /// `opts.channels` selects, as [`crate::select_channels`] says), with
    /// what the image's `omero` metadata says of each. The time point is
    /// `opts`'; the level is ignored (every level is used).
    pub fn open_channels(
        root: &Path,
        opts: &ReadOptions,
        brick: u32,
        apron: u32,
    ) -> Result<(brickray_core::ChannelSource, Vec<crate::ChannelInfo>), IoError> {
        let zarr = OmeZarr::open(root)?;
        ZarrBrickSource::channels_with(root, zarr, opts, |o| {
            ZarrBrickSource::open(root, o, brick, apron, None)
        })
    }

    /// [`ZarrBrickSource::open_channels`] of the image whose objects
    /// `reader` reads by key (see [`ZarrBrickSource::open_objects`]).
    pub fn open_channels_objects(
        reader: Arc<dyn ObjectReader>,
        opts: &ReadOptions,
        brick: u32,
        apron: u32,
    ) -> Result<(brickray_core::ChannelSource, Vec<crate::ChannelInfo>), IoError> {
        let root = PathBuf::from(reader.location());
        let zarr = OmeZarr::open_objects(reader.clone())?;
        ZarrBrickSource::channels_with(&root, zarr, opts, |o| {
            ZarrBrickSource::open_objects(reader.clone(), o, brick, apron, None)
        })
    }

    /// The selected channels of `zarr`, each opened by `open` with its
    /// channel chosen, as one channel source.
    fn channels_with(
        root: &Path,
        zarr: OmeZarr,
        opts: &ReadOptions,
        open: impl Fn(&ReadOptions) -> Result<ZarrBrickSource, IoError>,
    ) -> Result<(brickray_core::ChannelSource, Vec<crate::ChannelInfo>), IoError> {
        zarr.check_choice(&opts.clone().channel(None))?;
        let indices = crate::select_channels(root, zarr.channel_count(), opts)?;
        let info = indices.iter().map(|&c| zarr.channel_info(c)).collect();
        let parts = indices
            .iter()
            .map(|&c| {
                let o = opts.clone().channels(None).channel(Some(c));
                Ok(Arc::new(open(&o)?) as Arc<dyn brickray_core::BrickSource>)
            })
            .collect::<Result<Vec<_>, IoError>>()?;
        let source =
            brickray_core::ChannelSource::new(parts).map_err(|source| IoError::Channels {
                path: root.to_owned(),
                source,
            })?;
        Ok((source, info))
    }

    fn with(
        zarr: OmeZarr,
        opts: &ReadOptions,
        brick: u32,
        apron: u32,
        value_range: Option<[f32; 2]>,
    ) -> Result<ZarrBrickSource, IoError> {
        let root = zarr.root.clone();
        let root = root.as_path();
        let (_, c, t) = zarr.check_choice(&ReadOptions {
            level: None,
            ..opts.clone()
        })?;
        let dims64 = zarr.dims(0);
        brickray_core::volume::voxel_count(dims64).map_err(|e| IoError::volume(root, e))?;
        let range = match value_range {
            Some([a, b]) => [a as f64, b as f64],
            None => scan(&zarr, 0, c, t)?,
        };
        let conv = SampleConverter::choose(zarr.src, false, 1.0, 0.0, Some(range));
        let (s, _) = zarr.xyz(0);
        let desc = zarr.volume_desc(root, dims64, conv.dst, s, range)?;
        let layout = OctreeLayout::new(desc, brick, apron);
        // Each pyramid level's factor per axis, as a power of two.
        let (s0, _) = zarr.xyz(0);
        let factors: Vec<[u64; 3]> = (0..zarr.levels.len())
            .map(|m| {
                let (sm, _) = zarr.xyz(m);
                [0, 1, 2].map(|a| {
                    let r = (sm[a] / s0[a]).max(1.0);
                    1u64 << (r.log2().round().clamp(0.0, 40.0) as u32)
                })
            })
            .collect();
        let plan = (0..layout.levels)
            .map(|l| {
                let f = 1u64 << (layout.levels - 1 - l);
                let best = (0..factors.len())
                    .filter(|&m| factors[m].iter().all(|&x| x <= f))
                    .max_by_key(|&m| factors[m].iter().product::<u64>())
                    .unwrap_or(0);
                (best, factors[best].map(|x| f / x))
            })
            .collect::<Vec<(usize, [u64; 3])>>();
        // One brick reads its footprint at the pyramid level planned for it
        // whole: a pyramid too shallow for the volume (or a shape forged
        // huge) is refused here rather than allocated for when it is read.
        let side = layout.stored_side() as u64;
        for (l, &(m, r)) in plan.iter().enumerate() {
            let md = zarr.dims(m);
            let n = [0, 1, 2].map(|a| side.saturating_mul(r[a]).min(md[a]));
            let voxels = n.iter().try_fold(1u64, |v, &x| v.checked_mul(x));
            if voxels.is_none_or(|v| v > MAX_BRICK_READ) {
                return Err(IoError::unsupported(
                    root,
                    format!(
                        "a brick of octree level {l} reads {n:?} voxels (x, y, z) of pyramid \
                         level {m}, more than {MAX_BRICK_READ}: the image has too few levels \
                         to stream; build a store from it"
                    ),
                ));
            }
        }
        Ok(ZarrBrickSource {
            zarr,
            c,
            t,
            layout,
            conv,
            plan,
            nodes: Mutex::new(HashMap::new()),
        })
    }

    /// What was assumed where the metadata did not say (see
    /// [`VolumeReader::warnings`]), one line each.
    pub fn warnings(&self) -> Vec<String> {
        self.zarr.warnings.clone()
    }

    /// The image: its levels, version, and decoded-chunk cache
    /// ([`OmeZarr::chunk_cache_stats`], [`OmeZarr::set_chunk_cache_budget`]).
    pub fn image(&self) -> &OmeZarr {
        &self.zarr
    }

    /// Where the volume lies (the finest level's transforms).
    pub fn placement(&self) -> Placement {
        let (s, t) = self.zarr.xyz(0);
        Placement::axis_aligned(s, t, "image")
    }

    /// Values (rescaled, f64) of the octree-level box `lo..=hi`, x fastest.
    fn values(&self, level: u8, lo: [u64; 3], hi: [u64; 3]) -> Result<Vec<f64>, IoError> {
        let (m, r) = self.plan[level as usize];
        let md = self.zarr.dims(m);
        let zlo = [0, 1, 2].map(|a| (lo[a] * r[a]).min(md[a] - 1));
        let zhi = [0, 1, 2].map(|a| ((hi[a] + 1) * r[a]).min(md[a]).max(zlo[a] + 1));
        let bytes = self.zarr.region(m, self.c, self.t, zlo, zhi)?;
        let n = self.zarr.src.size();
        let src: Vec<f64> = bytes.chunks_exact(n).map(|s| self.conv.value(s)).collect();
        if r == [1, 1, 1] {
            return Ok(src);
        }
        let zn = [0, 1, 2].map(|a| zhi[a] - zlo[a]);
        let out_n = [0, 1, 2].map(|a| hi[a] - lo[a] + 1);
        let mut out = Vec::with_capacity((out_n[0] * out_n[1] * out_n[2]) as usize);
        for k in 0..out_n[2] {
            for j in 0..out_n[1] {
                for i in 0..out_n[0] {
                    let (mut sum, mut cnt) = (0.0, 0.0);
                    let o = [i, j, k];
                    let start = [0, 1, 2].map(|a| ((lo[a] + o[a]) * r[a]).min(md[a] - 1) - zlo[a]);
                    for dz in 0..r[2] {
                        let z = (start[2] + dz).min(zn[2] - 1);
                        for dy in 0..r[1] {
                            let y = (start[1] + dy).min(zn[1] - 1);
                            for dx in 0..r[0] {
                                let x = (start[0] + dx).min(zn[0] - 1);
                                sum += src[((z * zn[1] + y) * zn[0] + x) as usize];
                                cnt += 1.0;
                            }
                        }
                    }
                    out.push(sum / cnt);
                }
            }
        }
        Ok(out)
    }

    fn check(&self, key: NodeKey) -> Result<bool, BrickError> {
        let n = 1u64 << key.level.min(63);
        if key.level >= self.layout.levels || [key.x, key.y, key.z].iter().any(|&p| p as u64 >= n) {
            return Err(BrickError::OutOfRange { key });
        }
        Ok(self.layout.in_volume(key))
    }

    /// A failed read as a brick error: an I/O failure (a remote one among
    /// them, its typed error kept as the source) as [`BrickError::Io`],
    /// anything else (a corrupt chunk) as [`BrickError::Corrupt`].
    fn brick_err(key: NodeKey, e: IoError) -> BrickError {
        match e {
            IoError::Io { source, .. } => BrickError::Io { key, source },
            e => BrickError::Corrupt {
                key,
                reason: e.to_string(),
            },
        }
    }
}

/// Bricks of 1..=4096 voxels, the apron at most the brick.
fn check_brick(root: &Path, brick: u32, apron: u32) -> Result<(), IoError> {
    if brick == 0 || brick > 1 << 12 || apron > brick {
        return Err(IoError::unsupported(
            root,
            format!(
                "bricks of {brick} voxels with an apron of {apron} (1..=4096, apron at most the brick)"
            ),
        ));
    }
    Ok(())
}

fn store_value(dst: DType, v: f64, out: &mut [u8]) {
    match dst {
        DType::U8 => out[0] = v.round() as u8,
        DType::U16 => out.copy_from_slice(&(v.round() as u16).to_le_bytes()),
        DType::I16 => out.copy_from_slice(&(v.round() as i16).to_le_bytes()),
        _ => out.copy_from_slice(&(v as f32).to_le_bytes()),
    }
}

impl BrickSource for ZarrBrickSource {
    fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        if !self.check(key)? {
            return Ok(NodeInfo {
                kind: NodeKind::Empty,
                min: 0.0,
                max: 0.0,
                error: None,
                parent_error: None,
                channels: Default::default(),
                channel_errors: None,
            });
        }
        if let Some(n) = self.nodes.lock().get(&key) {
            return Ok(n.clone());
        }
        let (lo, hi) = self.layout.brick_footprint(key);
        let v = self
            .values(key.level, lo, hi)
            .map_err(|e| Self::brick_err(key, e))?;
        let (mn, mx) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        // as stored: integer types round
        let q = |x: f64| {
            let mut b = [0u8; 4];
            let n = self.layout.dtype().size();
            store_value(self.layout.dtype(), x, &mut b[..n]);
            brickray_core::VolumeData::from_le_bytes(self.layout.dtype(), &b[..n]).get(0)
        };
        let (mn, mx) = (q(mn), q(mx));
        let info = NodeInfo {
            kind: if mn == mx {
                NodeKind::Uniform(mn)
            } else {
                NodeKind::Data
            },
            min: mn,
            max: mx,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        };
        self.nodes.lock().insert(key, info.clone());
        Ok(info)
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        let expected = self.layout.brick_bytes();
        if out.len() != expected {
            return Err(BrickError::BufferSize {
                expected,
                actual: out.len(),
            });
        }
        let dst = self.layout.dtype();
        let sz = dst.size();
        if !self.check(key)? {
            let lo = self.layout.volume.value_range[0] as f64;
            for o in out.chunks_exact_mut(sz) {
                store_value(dst, lo, o);
            }
            return Ok(());
        }
        let fp = self.layout.brick_footprint(key);
        let vals = self
            .values(key.level, fp.0, fp.1)
            .map_err(|e| Self::brick_err(key, e))?;
        let mut o = 0;
        self.layout.gather_brick(key, fp, |i| {
            store_value(dst, vals[i], &mut out[o..o + sz]);
            o += sz;
        });
        Ok(())
    }

    /// [`ZARR_BATCH`] bricks per call over the network, 1 from a folder.
    fn batch_size(&self) -> usize {
        if self.zarr.store.is_local() {
            1
        } else {
            ZARR_BATCH
        }
    }

    /// The bricks at once, each on a thread of its own: their chunks are
    /// requested together, so a batch costs about the round trips of one
    /// brick (chunks two bricks share are fetched once, by the decoded-chunk
    /// cache). A brick not begun when `cancel` is cancelled is skipped, and
    /// the chunk requests of one begun are aborted (through
    /// [`CancelToken::scope`](brickray_core::CancelToken::scope), which an
    /// image over the network's object reads watch): it fails as
    /// [`BrickError::Cancelled`].
    fn read_bricks(
        &self,
        keys: &[NodeKey],
        outs: &mut [&mut [u8]],
        cancel: &brickray_core::CancelToken,
    ) -> Vec<Result<(), BrickError>> {
        on_threads(keys.iter().zip(outs.iter_mut()), |(&key, out)| {
            if cancel.is_cancelled() {
                Err(BrickError::Cancelled { key })
            } else {
                // The chunk reads under it abort when `cancel` is cancelled.
                match cancel.scope(|| self.read_brick(key, out)) {
                    Err(_) if cancel.is_cancelled() => Err(BrickError::Cancelled { key }),
                    r => r,
                }
            }
        })
    }

    /// Over the network, every node on a thread of its own: a node's
    /// metadata is read from its data, so eight children cost about the
    /// round trips of one, not eight times them.
    fn nodes(&self, keys: &[NodeKey]) -> Vec<Result<NodeInfo, BrickError>> {
        if self.zarr.store.is_local() {
            keys.iter().map(|&key| self.node(key)).collect()
        } else {
            on_threads(keys.iter(), |&key| self.node(key))
        }
    }
}

/// `f` of every item, each on a scoped thread of its own, in order (a panic
/// goes on to the caller).
fn on_threads<I: Send, T: Send>(
    items: impl Iterator<Item = I>,
    f: impl Fn(I) -> T + Sync,
) -> Vec<T> {
    std::thread::scope(|scope| {
        let f = &f;
        let runs: Vec<_> = items.map(|item| scope.spawn(move || f(item))).collect();
        runs.into_iter()
            .map(|r| r.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    })
}

/// Bricks an OME-Zarr image read over the network reads per call
/// ([`BrickSource::batch_size`]).
pub const ZARR_BATCH: usize = 16;
