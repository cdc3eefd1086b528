//! The streaming, parallel builder.
//!
//! The input is read one z-slice at a time. Every level of the pyramid keeps a
//! rolling window of whole xy-slices of its level volume: as soon as a level holds
//! the slices a row of bricks needs (`brick + 2 * apron`, clamped at the volume's
//! edges), that brick slab is cut, classified and compressed in parallel and its
//! payloads appended to the file; as soon as it holds the two slices a coarser
//! slice filters from, that slice is computed (in parallel over rows) and pushed
//! to the next coarser level. Slices no longer needed are dropped, so memory is
//! about `(brick + 2 * apron + 2) * 4/3` finest slices whatever the depth.
//!
//! When the slices are too large for that pass to fit the memory bound, the
//! finest level is built alone in y-bands (one pass over the input per band of
//! brick rows), writing the next coarser level volume to a temporary raw file
//! that is the input of the remaining levels (see `docs/store-format.md`).
//!
//! Children are always cut before their parent, so an inner node's min/max is the
//! union of its own stored voxels and its children's ranges (the range of the
//! whole subtree), and the empty threshold applies to that subtree range.

use crate::error::StoreError;
use crate::format::{
    ENTRY_LEN, Entry, FLAG_THRESHOLD, HEADER_LEN, Header, KIND_DATA, KIND_EMPTY, KIND_UNIFORM,
    MAX_APRON, MAX_BRICK, MAX_BRICK_BYTES, TableGeometry, VERSION, dtype_code, filter_code,
};
use crate::partial::{PartialFile, parent_dir, remove_stale};
use crate::sample::{Sample, range_dyn, with_sample};
use crate::{Filter, NO_ENTRY_LEVEL};
use brickray_core::io::FileKind;
use brickray_core::{NodeKey, OctreeLayout, VolumeReader};
use rayon::prelude::*;
use std::collections::VecDeque;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of a build.
#[derive(Debug, Clone, PartialEq)]
pub struct BuildOptions {
    /// Interior voxels per brick side (default 32).
    pub brick: u32,
    /// Apron voxels on each side of a brick (default 2, see `docs/store-format.md`).
    pub apron: u32,
    /// The 2x downsampling filter of inner nodes (default [`Filter::Average`]).
    pub filter: Filter,
    /// Nodes whose whole subtree lies strictly below this raw value are stored as
    /// empty, without payload (default: none).
    pub empty_below: Option<f32>,
    /// Upper bound in bytes on the builder's buffers (default 1 GiB).
    pub memory_bound: u64,
    /// Show a progress bar on stderr (default false).
    pub progress: bool,
}

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions {
            brick: 32,
            apron: 2,
            filter: Filter::Average,
            empty_below: None,
            memory_bound: 1 << 30,
            progress: false,
        }
    }
}

/// What a build did.
#[derive(Debug, Clone, PartialEq)]
pub struct BuildReport {
    /// The octree geometry.
    pub layout: OctreeLayout,
    /// Nodes in the table (every node that overlaps the volume).
    pub nodes: u64,
    /// Nodes with a payload.
    pub data_nodes: u64,
    /// Uniform nodes.
    pub uniform_nodes: u64,
    /// Empty nodes.
    pub empty_nodes: u64,
    /// Input voxels.
    pub input_voxels: u64,
    /// Input bytes.
    pub input_bytes: u64,
    /// Bytes of payload written.
    pub payload_bytes: u64,
    /// Uncompressed bytes of the bricks stored with a payload.
    pub raw_payload_bytes: u64,
    /// Size of the store file.
    pub file_bytes: u64,
    /// The builder's estimate of its peak buffer bytes.
    pub buffer_estimate: u64,
    /// Levels built in y-bands (several passes over their input) because one
    /// streaming pass would not fit the memory bound; 0 for a single pass.
    pub banded_levels: u8,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Builds a store at `out` from the volume file at `input` (any format
/// `brickray_core::io::open` reads, with its default, strict options).
pub fn build_file(
    input: &Path,
    out: &Path,
    opts: &BuildOptions,
) -> Result<BuildReport, StoreError> {
    let mut reader = brickray_core::io::open(input)?;
    build(reader.as_mut(), out, opts)
}

/// Builds a store at `out` from `reader`. The file is written under a temporary
/// name in the same directory (`.<name>.brickray-partial.<pid>-<seq>`) and
/// renamed only when complete; temporaries are removed on error, and stale
/// ones of earlier builds (their process gone) are removed first.
///
/// `out` must not be one of the reader's input files
/// ([`VolumeReader::input_files`], compared by file identity, so links and
/// other spellings are caught: [`StoreError::OutputIsInput`]), and if it exists
/// it must be a regular file ([`StoreError::OutputNotRegularFile`]).
pub fn build(
    reader: &mut dyn VolumeReader,
    out: &Path,
    opts: &BuildOptions,
) -> Result<BuildReport, StoreError> {
    let t0 = Instant::now();
    let inputs = reader.input_files();
    check_output(out, &inputs)?;
    let desc = reader.desc().clone();
    desc.validate().map_err(|e| StoreError::BadOption {
        option: "input",
        reason: e.to_string(),
    })?;
    if opts.brick == 0 || opts.brick > MAX_BRICK {
        return Err(StoreError::BadOption {
            option: "brick",
            reason: format!("must be in 1..={MAX_BRICK}"),
        });
    }
    if opts.apron > MAX_APRON {
        return Err(StoreError::BadOption {
            option: "apron",
            reason: format!("must be in 0..={MAX_APRON}"),
        });
    }
    if opts.memory_bound == 0 {
        return Err(StoreError::BadOption {
            option: "memory_bound",
            reason: "must be > 0 bytes".into(),
        });
    }
    if opts.empty_below.is_some_and(|t| !t.is_finite()) {
        return Err(StoreError::BadOption {
            option: "empty_below",
            reason: "must be finite".into(),
        });
    }
    let layout = OctreeLayout::new(desc.clone(), opts.brick, opts.apron);
    if layout.brick_bytes() > MAX_BRICK_BYTES {
        return Err(StoreError::BadOption {
            option: "brick",
            reason: format!(
                "a stored brick would take {} bytes (max {MAX_BRICK_BYTES})",
                layout.brick_bytes()
            ),
        });
    }
    let geo = TableGeometry::new(&layout).ok_or_else(|| StoreError::BadOption {
        option: "input",
        reason: "too many nodes".into(),
    })?;
    // Compressed output of one group of bricks, per-thread scratch, the table.
    let group_cap: u64 = (32u64 << 20)
        .min(opts.memory_bound / 8)
        .max(layout.brick_bytes() as u64 * 2);
    let threads = rayon::current_num_threads() as u64;
    let scratch = threads * 3 * layout.brick_bytes() as u64;
    let table = geo.count.saturating_mul(ENTRY_LEN as u64 + 48);
    let fixed = group_cap
        .saturating_add(scratch)
        .saturating_add(table)
        .saturating_add((8u64 << 20).min(opts.memory_bound / 16));
    let top = layout.levels - 1;
    let first_plan = plan(&layout, top, opts.memory_bound, fixed)?;
    let needed = first_plan.need();
    remove_stale(parent_dir(out));
    let tmp = PartialFile::create(out)?;
    let tmp_path: PathBuf = tmp.path().to_owned();
    let mut w = BufWriter::with_capacity(4 << 20, tmp.file());
    // Placeholder header: all zeros never opens as a store.
    w.write_all(&[0u8; HEADER_LEN])
        .map_err(|e| StoreError::io(&tmp_path, e))?;

    let fill_entry = Entry {
        level: NO_ENTRY_LEVEL,
        kind: KIND_EMPTY,
        pos: [0; 3],
        min: 0.0,
        max: 0.0,
        value: 0.0,
        len: 0,
        offset: 0,
        crc: 0,
    };
    let mut ctx = Ctx {
        layout: layout.clone(),
        geo,
        filter: opts.filter,
        empty_below: opts.empty_below,
        entries: Vec::new(),
        offset: HEADER_LEN as u64,
        group_cap,
        path: tmp_path.clone(),
        data_range: [f32::INFINITY, f32::NEG_INFINITY],
        raw_payload: 0,
    };
    ctx.entries = vec![fill_entry; ctx.geo.count as usize];

    let pb = if opts.progress {
        let pb = indicatif::ProgressBar::new(desc.voxel_count());
        pb.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {wide_bar} {percent}% {human_pos}/{human_len} voxels, \
                 {per_sec}, {eta} left",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        pb
    } else {
        indicatif::ProgressBar::hidden()
    };

    // Levels `0..=top` remain to be built from `input` (the level-`top` volume):
    // in one streaming pass when that fits the bound, else level `top` alone in
    // y-bands (several passes over the input), writing the level `top - 1`
    // volume to a temporary file that becomes the next input.
    let mut top = top;
    let mut owned: Option<brickray_core::io::RawReader> = None;
    let mut _level_file: Option<PartialFile> = None;
    let mut cur_plan = first_plan;
    let mut banded = 0u8;
    loop {
        let input: &mut dyn VolumeReader = match owned.as_mut() {
            Some(r) => r,
            None => &mut *reader,
        };
        match cur_plan {
            Plan::Stream { per, .. } => {
                run_stream(&mut ctx, input, top, per, &mut w, &pb)?;
                break;
            }
            Plan::Bands { band_bricks, .. } => {
                let pdims = layout.level_dims(top - 1);
                let f = PartialFile::create(out)?;
                let plen =
                    pdims.iter().map(|&d| d as u64).product::<u64>() * layout.dtype().size() as u64;
                f.file()
                    .set_len(plen)
                    .map_err(|e| StoreError::io(f.path(), e))?;
                run_bands(
                    &mut ctx,
                    input,
                    top,
                    band_bricks,
                    f.file(),
                    f.path(),
                    &mut w,
                    &pb,
                )?;
                let pdesc = brickray_core::VolumeDesc {
                    dims: pdims,
                    ..layout.volume.clone()
                };
                owned = Some(brickray_core::io::RawReader::new(f.path(), 0, pdesc)?);
                _level_file = Some(f);
                top -= 1;
                banded += 1;
                cur_plan = plan(&layout, top, opts.memory_bound, fixed)?;
            }
        }
    }
    if ctx.entries.iter().any(|e| e.level == NO_ENTRY_LEVEL) {
        return Err(StoreError::BadOption {
            option: "input",
            reason: "internal: octree not complete".into(),
        });
    }
    pb.finish_and_clear();

    // Node table, then the header.
    let table_offset = ctx.offset;
    let mut table = vec![0u8; ctx.entries.len() * ENTRY_LEN];
    let (mut data_nodes, mut uniform_nodes, mut empty_nodes) = (0, 0, 0);
    for (e, b) in ctx.entries.iter().zip(table.chunks_exact_mut(ENTRY_LEN)) {
        match e.kind {
            KIND_DATA => data_nodes += 1,
            KIND_UNIFORM => uniform_nodes += 1,
            _ => empty_nodes += 1,
        }
        e.encode(b);
    }
    w.write_all(&table)
        .map_err(|e| StoreError::io(&tmp_path, e))?;
    let data_range = if ctx.data_range[0] <= ctx.data_range[1] {
        ctx.data_range
    } else {
        [0.0, 0.0]
    };
    let header = Header {
        version: VERSION,
        header_len: HEADER_LEN as u32,
        dims: desc.dims,
        dtype: dtype_code(desc.dtype),
        filter: filter_code(opts.filter),
        flags: if opts.empty_below.is_some() {
            FLAG_THRESHOLD
        } else {
            0
        },
        levels: layout.levels,
        brick: layout.brick,
        apron: layout.apron,
        spacing: desc.spacing,
        value_range: desc.value_range,
        data_range,
        empty_below: opts.empty_below.unwrap_or(0.0),
        node_count: ctx.entries.len() as u64,
        table_offset,
        table_len: table.len() as u64,
        payload_bytes: table_offset - HEADER_LEN as u64,
        table_crc: crc32fast::hash(&table),
    };
    w.seek(SeekFrom::Start(0))
        .map_err(|e| StoreError::io(&tmp_path, e))?;
    w.write_all(&header.encode())
        .map_err(|e| StoreError::io(&tmp_path, e))?;
    w.flush().map_err(|e| StoreError::io(&tmp_path, e))?;
    drop(w);
    tmp.file()
        .sync_all()
        .map_err(|e| StoreError::io(&tmp_path, e))?;
    // Again: the output may have been replaced while the build ran.
    check_output(out, &inputs)?;
    tmp.persist(out)?;
    let file_bytes = table_offset + table.len() as u64;
    Ok(BuildReport {
        layout,
        nodes: ctx.entries.len() as u64,
        data_nodes,
        uniform_nodes,
        empty_nodes,
        input_voxels: desc.voxel_count(),
        input_bytes: desc.byte_len(),
        payload_bytes: table_offset - HEADER_LEN as u64,
        raw_payload_bytes: ctx.raw_payload,
        file_bytes,
        buffer_estimate: needed,
        banded_levels: banded,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Refuses an output that exists and is not a regular file, or that is one of
/// the build's input files (by file identity).
fn check_output(out: &Path, inputs: &[PathBuf]) -> Result<(), StoreError> {
    let md = match std::fs::metadata(out) {
        Ok(md) => md,
        // Nothing there yet (or a dangling link, which the rename replaces).
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(StoreError::io(out, e)),
    };
    if let Some(kind) = FileKind::of(md.file_type()) {
        return Err(StoreError::OutputNotRegularFile {
            path: out.to_owned(),
            kind,
        });
    }
    for input in inputs {
        if let Ok(im) = std::fs::metadata(input)
            && same_file(out, &md, input, &im)
        {
            return Err(StoreError::OutputIsInput {
                output: out.to_owned(),
                input: input.clone(),
            });
        }
    }
    Ok(())
}

/// Whether two paths name the same file: device and inode on unix, else the
/// canonical paths.
#[cfg(unix)]
fn same_file(_a: &Path, a: &std::fs::Metadata, _b: &Path, b: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    a.dev() == b.dev() && a.ino() == b.ino()
}

/// Whether two paths name the same file: device and inode on unix, else the
/// canonical paths.
#[cfg(not(unix))]
fn same_file(a: &Path, _: &std::fs::Metadata, b: &Path, _: &std::fs::Metadata) -> bool {
    matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

/// Shared state of a build.
struct Ctx {
    layout: OctreeLayout,
    geo: TableGeometry,
    filter: Filter,
    empty_below: Option<f32>,
    entries: Vec<Entry>,
    offset: u64,
    group_cap: u64,
    path: PathBuf,
    data_range: [f32; 2],
    raw_payload: u64,
}

/// The rolling window of one level's slices.
struct LevelBuf {
    level: u8,
    dims: [u32; 3],
    grid: [u32; 3],
    /// `slices[i]` is level slice `base + i`.
    slices: VecDeque<Vec<u8>>,
    /// Dropped slice buffers, reused (avoids page faults on fresh allocations).
    pool: Vec<Vec<u8>>,
    pool_cap: usize,
    base: u32,
    next_slab: u32,
    next_down: u32,
    /// The slices hold level rows `row0..row0 + nrows` (all rows when streaming).
    row0: u32,
    nrows: u32,
    /// Brick rows (y) this pass cuts.
    by: (u32, u32),
}

impl LevelBuf {
    fn new(layout: &OctreeLayout, level: u8, per: u32) -> LevelBuf {
        let dims = layout.level_dims(level);
        LevelBuf {
            level,
            dims,
            grid: dims.map(|d| d.div_ceil(layout.brick)),
            slices: VecDeque::new(),
            pool: Vec::new(),
            pool_cap: per as usize,
            base: 0,
            next_slab: 0,
            next_down: 0,
            row0: 0,
            nrows: dims[1],
            by: (0, dims[1].div_ceil(layout.brick)),
        }
    }

    /// A slice buffer of `len` bytes (contents unspecified).
    fn take_buffer(&mut self, len: usize) -> Vec<u8> {
        let mut b = self.pool.pop().unwrap_or_default();
        b.resize(len, 0);
        b
    }

    fn received(&self) -> u32 {
        self.base + self.slices.len() as u32
    }

    fn slice(&self, z: u32) -> &[u8] {
        &self.slices[(z - self.base) as usize]
    }

    /// Cuts every ready brick slab, filters every ready coarser slice into
    /// `sink`, and drops slices no longer needed.
    fn process<W: Write>(
        &mut self,
        ctx: &mut Ctx,
        mut sink: Sink<'_>,
        w: &mut W,
    ) -> Result<(), StoreError> {
        let b = ctx.layout.brick;
        let a = ctx.layout.apron;
        let nz = self.dims[2];
        while self.next_slab < self.grid[2] {
            let need = ((self.next_slab as u64 + 1) * b as u64 + a as u64).min(nz as u64) as u32;
            if self.received() < need {
                break;
            }
            self.emit_slab(ctx, w)?;
            self.next_slab += 1;
        }
        let has_parent = !matches!(sink, Sink::None);
        if has_parent {
            let pdims = ctx.layout.level_dims(self.level - 1);
            let size = ctx.layout.dtype().size();
            while self.next_down < pdims[2] {
                let need = (2 * self.next_down + 2).min(nz);
                if self.received() < need {
                    break;
                }
                match &mut sink {
                    Sink::Level(p) => {
                        let mut s = p.take_buffer(pdims[0] as usize * pdims[1] as usize * size);
                        self.downsample(ctx, self.next_down, pdims, (0, pdims[1]), &mut s);
                        p.slices.push_back(s);
                    }
                    Sink::File {
                        file,
                        path,
                        rows,
                        buf,
                    } => {
                        let (j0, j1) = *rows;
                        buf.resize((j1 - j0) as usize * pdims[0] as usize * size, 0);
                        self.downsample(ctx, self.next_down, pdims, (j0, j1), buf);
                        let off = ((self.next_down as u64 * pdims[1] as u64 + j0 as u64)
                            * pdims[0] as u64)
                            * size as u64;
                        file.write_all_at(buf, off)
                            .map_err(|e| StoreError::io(path, e))?;
                    }
                    Sink::None => {}
                }
                self.next_down += 1;
            }
        }
        // Keep what the next slab and the next coarser slice need.
        let keep_slab = (self.next_slab as u64 * b as u64).saturating_sub(a as u64);
        let keep_slab = if self.next_slab >= self.grid[2] {
            u64::MAX
        } else {
            keep_slab
        };
        let keep_down = if has_parent && self.next_down < self.dims[2].div_ceil(2) {
            2 * self.next_down as u64
        } else {
            u64::MAX
        };
        let keep = keep_slab.min(keep_down);
        while !self.slices.is_empty() && (self.base as u64) < keep {
            if let Some(b) = self.slices.pop_front()
                && self.pool.len() < self.pool_cap
            {
                self.pool.push(b);
            }
            self.base += 1;
        }
        Ok(())
    }

    /// Rows `rows` of level slice `k` of the coarser level, filtered from
    /// slices `2k`, `2k+1`.
    fn downsample(&self, ctx: &Ctx, k: u32, pdims: [u32; 3], rows: (u32, u32), out: &mut [u8]) {
        let nz = self.dims[2];
        let s0 = self.slice(2 * k);
        let s1 = self.slice((2 * k + 1).min(nz - 1));
        let dtype = ctx.layout.dtype();
        let g = Geom {
            nx: self.dims[0] as usize,
            ny: self.dims[1] as usize,
            row0: self.row0 as usize,
            px: pdims[0] as usize,
            rows: (rows.0 as usize, rows.1 as usize),
        };
        debug_assert_eq!(out.len(), g.px * (g.rows.1 - g.rows.0) * dtype.size());
        with_sample!(dtype, T => downsample_slice::<T>(s0, s1, &g, ctx.filter, out));
    }

    /// Cuts, classifies, compresses and writes the bricks of slab `next_slab`.
    fn emit_slab<W: Write>(&self, ctx: &mut Ctx, w: &mut W) -> Result<(), StoreError> {
        let bz = self.next_slab;
        let [gx, _, _] = self.grid;
        let (by_start, gy) = self.by;
        let bb = ctx.layout.brick_bytes() as u64;
        let rows_per_group = (ctx.group_cap / (bb * gx as u64).max(1)).max(1) as u32;
        let mut by0 = by_start;
        while by0 < gy {
            let by1 = (by0 + rows_per_group).min(gy);
            let keys: Vec<NodeKey> = (by0..by1)
                .flat_map(|by| (0..gx).map(move |bx| (bx, by)))
                .map(|(bx, by)| NodeKey::new(self.level, bx, by, bz))
                .collect();
            let shared: &Ctx = ctx;
            let results: Vec<(Entry, Option<Vec<u8>>)> = keys
                .par_iter()
                .map_init(
                    || vec![0u8; bb as usize],
                    |buf, &key| self.cut_brick(shared, key, buf),
                )
                .collect();
            if let Some((e, _)) = results
                .iter()
                .find(|(e, _)| !(e.min.is_finite() && e.max.is_finite()))
            {
                return Err(StoreError::NonFinite { key: e.key() });
            }
            for (mut e, payload) in results {
                if let Some(p) = payload {
                    e.offset = ctx.offset;
                    e.len = p.len() as u32;
                    e.crc = crc32fast::hash(&p);
                    w.write_all(&p)
                        .map_err(|err| StoreError::io(&ctx.path, err))?;
                    ctx.offset += p.len() as u64;
                    ctx.raw_payload += bb;
                }
                if self.level + 1 == ctx.layout.levels {
                    ctx.data_range[0] = ctx.data_range[0].min(e.min);
                    ctx.data_range[1] = ctx.data_range[1].max(e.max);
                }
                let i = ctx.geo.index(e.key()).unwrap_or(usize::MAX);
                if let Some(slot) = ctx.entries.get_mut(i) {
                    *slot = e;
                }
            }
            by0 = by1;
        }
        Ok(())
    }

    /// Cuts one brick into `buf` and returns its entry and compressed payload.
    fn cut_brick(&self, ctx: &Ctx, key: NodeKey, buf: &mut [u8]) -> (Entry, Option<Vec<u8>>) {
        let lay = &ctx.layout;
        let size = lay.dtype().size();
        let side = lay.stored_side() as i64;
        let a = lay.apron as i64;
        let b = lay.brick as i64;
        let [nx, ny, nz] = self.dims.map(|d| d as i64);
        let x0 = key.x as i64 * b - a;
        let y0 = key.y as i64 * b - a;
        let z0 = key.z as i64 * b - a;
        // x range of the row that lies inside the level volume.
        let in_lo = x0.max(0);
        let in_hi = (x0 + side).min(nx);
        let row = side as usize * size;
        for k in 0..side {
            let z = (z0 + k).clamp(0, nz - 1) as u32;
            let sl = self.slice(z);
            for j in 0..side {
                let y = (y0 + j).clamp(0, ny - 1) as usize - self.row0 as usize;
                let src_row = &sl[y * nx as usize * size..(y + 1) * nx as usize * size];
                let dst = &mut buf[((k * side + j) as usize) * row..][..row];
                // Left clamp.
                let left = (in_lo - x0) as usize;
                for i in 0..left {
                    dst[i * size..(i + 1) * size].copy_from_slice(&src_row[..size]);
                }
                let mid = (in_hi - in_lo).max(0) as usize;
                dst[left * size..(left + mid) * size].copy_from_slice(
                    &src_row[in_lo as usize * size..(in_lo as usize + mid) * size],
                );
                let last = &src_row[(nx as usize - 1) * size..nx as usize * size];
                for i in left + mid..side as usize {
                    dst[i * size..(i + 1) * size].copy_from_slice(last);
                }
            }
        }
        let (mut lo, mut hi) = range_dyn(lay.dtype(), buf);
        if lay.dtype() == brickray_core::DType::F32
            && buf
                .chunks_exact(4)
                .any(|c| !f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite())
        {
            (lo, hi) = (f32::NAN, f32::NAN);
        }
        let uniform = lo == hi;
        // Subtree range: own voxels and the children's ranges.
        let (mut smin, mut smax) = (lo, hi);
        if key.level + 1 < lay.levels {
            for c in key.children() {
                if let Some(e) = ctx.geo.index(c).and_then(|i| ctx.entries.get(i))
                    && e.level != NO_ENTRY_LEVEL
                {
                    smin = smin.min(e.min);
                    smax = smax.max(e.max);
                }
            }
        }
        let mut e = Entry {
            level: key.level,
            kind: KIND_DATA,
            pos: [key.x, key.y, key.z],
            min: smin,
            max: smax,
            value: lo,
            len: 0,
            offset: 0,
            crc: 0,
        };
        if ctx.empty_below.is_some_and(|t| smax < t) {
            e.kind = KIND_EMPTY;
            return (e, None);
        }
        if uniform {
            e.kind = KIND_UNIFORM;
            return (e, None);
        }
        let payload = lz4_flex::block::compress(buf);
        (e, Some(payload))
    }
}

/// Geometry of one downsampling step.
struct Geom {
    /// Fine level width and height.
    nx: usize,
    ny: usize,
    /// First fine row held in the slices.
    row0: usize,
    /// Coarse width.
    px: usize,
    /// Coarse rows to compute.
    rows: (usize, usize),
}

fn downsample_slice<T: Sample>(s0: &[u8], s1: &[u8], g: &Geom, filter: Filter, out: &mut [u8]) {
    let sz = T::SIZE;
    let (nx, ny, px) = (g.nx, g.ny, g.px);
    let row = |s: &'_ [u8], y: usize| -> std::ops::Range<usize> {
        let _ = s;
        (y - g.row0) * nx * sz..(y - g.row0 + 1) * nx * sz
    };
    let rows = out.par_chunks_mut(px * sz).with_min_len(8);
    rows.enumerate().for_each(|(jj, orow)| {
        let j = g.rows.0 + jj;
        let y0 = (2 * j).min(ny - 1);
        let y1 = (2 * j + 1).min(ny - 1);
        let r = [
            &s0[row(s0, y0)],
            &s0[row(s0, y1)],
            &s1[row(s1, y0)],
            &s1[row(s1, y1)],
        ];
        for i in 0..px {
            let x0 = (2 * i).min(nx - 1) * sz;
            let x1 = (2 * i + 1).min(nx - 1) * sz;
            // Order: x fastest, then y, then z.
            let v = [
                T::read(&r[0][x0..]),
                T::read(&r[0][x1..]),
                T::read(&r[1][x0..]),
                T::read(&r[1][x1..]),
                T::read(&r[2][x0..]),
                T::read(&r[2][x1..]),
                T::read(&r[3][x0..]),
                T::read(&r[3][x1..]),
            ];
            T::filter(v, filter).write(&mut orow[i * sz..]);
        }
    });
}

/// Where a level's filtered slices go.
enum Sink<'a> {
    /// Nowhere (the root level).
    None,
    /// The next coarser level's window.
    Level(&'a mut LevelBuf),
    /// Rows `rows` of each coarser slice, into a raw file of the coarser level.
    File {
        file: &'a std::fs::File,
        path: &'a Path,
        rows: (u32, u32),
        buf: &'a mut Vec<u8>,
    },
}

/// How the remaining levels are built.
#[derive(Debug, Clone, Copy)]
enum Plan {
    /// All levels `0..=top` in one streaming pass, reading `per` slices a step.
    Stream { per: u32, need: u64 },
    /// Level `top` alone, `band_bricks` brick rows per pass.
    Bands { band_bricks: u32, need: u64 },
}

impl Plan {
    fn need(&self) -> u64 {
        match *self {
            Plan::Stream { need, .. } | Plan::Bands { need, .. } => need,
        }
    }
}

/// Slices read per step for slices of `bytes` (at most ~8 MiB, at most a brick).
fn per_step(bytes: u64, brick: u32) -> u32 {
    ((8u64 << 20) / bytes.max(1)).clamp(1, brick as u64) as u32
}

/// Rows a band of `band_bricks` brick rows starting at brick row `by0` holds.
fn band_rows(layout: &OctreeLayout, ny: u32, by0: u32, by1: u32) -> (u32, u32) {
    let b = layout.brick as u64;
    let a = layout.apron as u64;
    let lo = (by0 as u64 * b).saturating_sub(a);
    let hi = (by1 as u64 * b + a.max(1)).min(ny as u64);
    (lo as u32, hi as u32)
}

/// Chooses how to build levels `0..=top` within `bound` bytes.
fn plan(layout: &OctreeLayout, top: u8, bound: u64, fixed: u64) -> Result<Plan, StoreError> {
    let d = layout.level_dims(top);
    let size = layout.dtype().size() as u64;
    let slice = d[0] as u64 * d[1] as u64 * size;
    let side = layout.stored_side() as u64;
    let per = per_step(slice, layout.brick);
    // Rolling windows: brick + 2 apron + 2 slices per level plus the slices read
    // in one step and as many recycled buffers; levels shrink 4x.
    let need = (side + 2 + 2 * per as u64) * slice * 4 / 3 + fixed;
    if need <= bound || top == 0 {
        return if need <= bound {
            Ok(Plan::Stream { per, need })
        } else {
            Err(StoreError::MemoryBound {
                needed: need,
                bound,
                slab: side * slice,
            })
        };
    }
    // Bands: one full input slice to read into, the band window, one band of
    // coarser rows.
    let gy = d[1].div_ceil(layout.brick);
    let band_need = |bb: u32| {
        let (lo, hi) = band_rows(layout, d[1], 0, bb.min(gy));
        let band = (hi - lo) as u64 * d[0] as u64 * size;
        let per = per_step(band, layout.brick) as u64;
        slice + (side + 2 + 2 * per) * band + band / 2 + fixed
    };
    let mut lo = 1u32;
    if band_need(lo) > bound {
        return Err(StoreError::MemoryBound {
            needed: band_need(lo),
            bound,
            slab: side * slice,
        });
    }
    let mut hi = gy;
    while lo < hi {
        let mid = (lo + hi).div_ceil(2);
        if band_need(mid) <= bound {
            lo = mid
        } else {
            hi = mid - 1
        }
    }
    Ok(Plan::Bands {
        band_bricks: lo,
        need: band_need(lo),
    })
}

/// Builds levels `0..=top` from the level-`top` volume in one streaming pass.
fn run_stream<W: Write>(
    ctx: &mut Ctx,
    input: &mut dyn VolumeReader,
    top: u8,
    per: u32,
    w: &mut W,
    pb: &indicatif::ProgressBar,
) -> Result<(), StoreError> {
    let layout = ctx.layout.clone();
    let mut levels: Vec<LevelBuf> = (0..=top).map(|l| LevelBuf::new(&layout, l, per)).collect();
    let finest = top as usize;
    let d = layout.level_dims(top);
    let slice_bytes = d[0] as usize * d[1] as usize * layout.dtype().size();
    let full = top + 1 == layout.levels;
    let mut z = 0;
    while z < d[2] {
        let z1 = (z + per).min(d[2]);
        for zi in z..z1 {
            let mut s = levels[finest].take_buffer(slice_bytes);
            input.read_slices(zi, zi + 1, &mut s)?;
            levels[finest].slices.push_back(s);
        }
        z = z1;
        for l in (0..=finest).rev() {
            let (coarse, fine) = levels.split_at_mut(l);
            let sink = match coarse.last_mut() {
                Some(p) => Sink::Level(p),
                None => Sink::None,
            };
            fine[0].process(ctx, sink, w)?;
        }
        if full {
            pb.set_position(z as u64 * d[0] as u64 * d[1] as u64);
        }
    }
    Ok(())
}

/// Builds level `top` in bands of `band_bricks` brick rows (one pass over the
/// input each), writing the level `top - 1` volume to `file`.
#[allow(clippy::too_many_arguments)]
fn run_bands<W: Write>(
    ctx: &mut Ctx,
    input: &mut dyn VolumeReader,
    top: u8,
    band_bricks: u32,
    file: &std::fs::File,
    path: &Path,
    w: &mut W,
    pb: &indicatif::ProgressBar,
) -> Result<(), StoreError> {
    let layout = ctx.layout.clone();
    let d = layout.level_dims(top);
    let pd = layout.level_dims(top - 1);
    let size = layout.dtype().size();
    let gy = d[1].div_ceil(layout.brick);
    let bands = gy.div_ceil(band_bricks);
    let full = top + 1 == layout.levels;
    let mut slice = vec![0u8; d[0] as usize * d[1] as usize * size];
    let mut out_rows = Vec::new();
    for band in 0..bands {
        let by0 = band * band_bricks;
        let by1 = (by0 + band_bricks).min(gy);
        let (r0, r1) = band_rows(&layout, d[1], by0, by1);
        // Coarser rows this band filters: every row whose source rows start here.
        let b = layout.brick as u64;
        let j0 = ((by0 as u64 * b).div_ceil(2)).min(pd[1] as u64) as u32;
        let j1 = if by1 == gy {
            pd[1]
        } else {
            ((by1 as u64 * b).div_ceil(2)).min(pd[1] as u64) as u32
        };
        let row_bytes = d[0] as usize * size;
        let band_bytes = (r1 - r0) as usize * row_bytes;
        let per = per_step(band_bytes as u64, layout.brick);
        let mut lb = LevelBuf::new(&layout, top, per);
        lb.row0 = r0;
        lb.nrows = r1 - r0;
        lb.by = (by0, by1);
        let mut z = 0;
        while z < d[2] {
            let z1 = (z + per).min(d[2]);
            for zi in z..z1 {
                input.read_slices(zi, zi + 1, &mut slice)?;
                let mut s = lb.take_buffer(band_bytes);
                s.copy_from_slice(&slice[r0 as usize * row_bytes..r1 as usize * row_bytes]);
                lb.slices.push_back(s);
            }
            z = z1;
            let sink = if j1 > j0 {
                Sink::File {
                    file,
                    path,
                    rows: (j0, j1),
                    buf: &mut out_rows,
                }
            } else {
                Sink::None
            };
            lb.process(ctx, sink, w)?;
            if full {
                let done = (band as u64 * d[2] as u64 + z as u64) * layout.volume.voxel_count();
                pb.set_position(done / (bands as u64 * d[2] as u64));
            }
        }
    }
    Ok(())
}
