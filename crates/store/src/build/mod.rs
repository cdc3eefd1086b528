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
    ENTRY_LEN, Entry, FLAG_ERRORS, FLAG_LABELS, FLAG_PARENT_ERRORS, FLAG_PLACEMENT,
    FLAG_SPLIT_MASKS, FLAG_SPREAD, FLAG_THRESHOLD, HEADER_LEN, Header, KIND_DATA, KIND_EMPTY,
    KIND_UNIFORM, MAGIC, MAX_APRON, MAX_BRICK, MAX_BRICK_BYTES, SPREAD_ENTRY_LEN, TableGeometry,
    VERSION, dtype_code, filter_code,
};
use crate::partial::{PartialFile, parent_dir, remove_stale};
use crate::{Filter, NO_ENTRY_LEVEL};
use brickray_core::OctreeLayout;
use brickray_io::FileKind;
use brickray_io::{Placement, VolumeReader};
use passes::{Files, Plan, plan, run_bands, run_stream};
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

mod errors;
mod label_errors;
mod level;
mod passes;
mod spread;
mod stage;

pub(crate) use spread::spread_brick_bytes;
use spread::{MomentFile, SpreadSink};

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
    /// Told the voxels of the finest level done so far and their total as the
    /// build goes (default: none). The command-line tool draws a progress
    /// bar with it.
    pub progress: Option<BuildProgress>,
    /// Build an anisotropic pyramid ([`OctreeLayout::anisotropic`]): coarser
    /// levels first halve only the axes with the finer voxel sides (default
    /// false: every level halves all axes). Volumes with near-isotropic voxels
    /// get the same store either way.
    pub anisotropic: bool,
    /// Record each coarse voxel's spread (format version 7, the spread
    /// section; default false): the standard deviation of the normalized
    /// values of the finest voxels it stands for, which the renderers
    /// classify coarse levels with ([`brickray_core::BrickSource::read_spread`]).
    /// Intensity volumes with the average filter only: a label map or
    /// another filter is refused ([`StoreError::BadOption`]). The moment
    /// windows (16 bytes a coarse voxel) count against `memory_bound`, and
    /// a banded build carries the moments through its temporary files.
    pub spread: bool,
}

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions {
            brick: 32,
            apron: 2,
            filter: Filter::Average,
            empty_below: None,
            memory_bound: 1 << 30,
            progress: None,
            anisotropic: false,
            spread: false,
        }
    }
}

/// A build's progress callback: `(done, total)` voxels of the finest level.
#[derive(Clone)]
pub struct BuildProgress(pub std::sync::Arc<dyn Fn(u64, u64) + Send + Sync>);

impl BuildProgress {
    fn report(&self, done: u64, total: u64) {
        (self.0)(done, total)
    }
}

impl std::fmt::Debug for BuildProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("BuildProgress(..)")
    }
}

impl PartialEq for BuildProgress {
    /// The same callback.
    fn eq(&self, other: &Self) -> bool {
        std::sync::Arc::ptr_eq(&self.0, &other.0)
    }
}

/// Where the build reports its progress: to the caller's callback, if any.
struct Progress<'a> {
    to: Option<&'a BuildProgress>,
    total: u64,
}

impl Progress<'_> {
    fn set_position(&self, done: u64) {
        if let Some(p) = self.to {
            p.report(done.min(self.total), self.total);
        }
    }
}

/// What a build did.
#[derive(Debug, Clone, PartialEq)]
pub struct BuildReport {
    /// Whether the store has the error section (per-node error bounds; left
    /// out when that pass would exceed the memory bound).
    pub errors: bool,
    /// The placement recorded in the store (the reader's
    /// [`VolumeReader::placement`]; `None` when the input does not say).
    pub placement: Option<Placement>,
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
    /// Whether the store records spreads (the spread section, format
    /// version 7: [`BuildOptions::spread`]).
    pub spread: bool,
    /// Bytes of spread payload written (0 without spreads).
    pub spread_bytes: u64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Builds a store at `out` from the volume file at `input` (any format
/// `brickray_io::open` reads, with its default, strict options).
pub fn build_file(
    input: &Path,
    out: &Path,
    opts: &BuildOptions,
) -> Result<BuildReport, StoreError> {
    let mut reader = brickray_io::open(input)?;
    build(reader.as_mut(), out, opts)
}

/// Builds a store at `out` from `reader`. The file is written under a temporary
/// name in the same directory (`.<name>.brickray-partial.<pid>-<seq>`), its
/// magic written last, after everything else is synced, and renamed only when
/// complete; temporaries are removed on error, and stale ones of earlier
/// builds (their process gone) are removed first. [`crate::open`] refuses a
/// temporary by its name ([`StoreError::PartialBuild`]).
///
/// `out` must not be one of the reader's input files
/// ([`VolumeReader::input_files`], compared by file identity, so links and
/// other spellings are caught: [`StoreError::OutputIsInput`]), and if it exists
/// it must be a regular file ([`StoreError::OutputNotRegularFile`]).
///
/// The reader's [`placement`](VolumeReader::placement), when it has one, is
/// recorded in the store ([`Store::placement`](crate::Store::placement)); one
/// the store cannot hold (a non-finite or singular affine, a last row other
/// than `0 0 0 1`, a space other than `RAS`, `LPS` and `image`) fails the
/// build before anything is written ([`StoreError::BadPlacement`]).
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
    // The placement record (format version 6), checked before anything is
    // written.
    let placement = reader.placement();
    let placement_bytes = placement
        .as_ref()
        .map(|p| crate::placement::encode(p, reader.path()))
        .transpose()?;
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
    // Label maps are filtered by the mode whatever the options say: an
    // average or a maximum of label ids invents labels.
    let labels = desc.kind.is_labels();
    let filter = if labels { Filter::Mode } else { opts.filter };
    if opts.spread && labels {
        return Err(StoreError::BadOption {
            option: "spread",
            reason: "a label map has no spread (its levels are the mode of their children)".into(),
        });
    }
    if opts.spread && filter != Filter::Average {
        return Err(StoreError::BadOption {
            option: "spread",
            reason: format!(
                "spreads describe box averages; the {filter:?} filter's coarse voxels are not"
            ),
        });
    }
    let layout = if opts.anisotropic {
        OctreeLayout::anisotropic(desc.clone(), opts.brick, opts.apron)
    } else {
        OctreeLayout::new(desc.clone(), opts.brick, opts.apron)
    };
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
    let spread_scratch = if opts.spread {
        3 * spread_brick_bytes(&layout) as u64
    } else {
        0
    };
    let scratch = threads * (3 * layout.brick_bytes() as u64 + spread_scratch);
    // The entries and their encoded table (and the spread table's entries).
    let per_node = ENTRY_LEN as u64
        + 48
        + if opts.spread {
            2 * SPREAD_ENTRY_LEN as u64
        } else {
            0
        };
    let table = geo.count.saturating_mul(per_node);
    let fixed = group_cap
        .saturating_add(scratch)
        .saturating_add(table)
        .saturating_add((8u64 << 20).min(opts.memory_bound / 16));
    let top = layout.levels - 1;
    let first_plan = plan(&layout, top, opts.memory_bound, fixed, opts.spread)?;
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
        filter,
        empty_below: opts.empty_below,
        entries: Vec::new(),
        offset: HEADER_LEN as u64,
        group_cap,
        path: tmp_path.clone(),
        data_range: [f32::INFINITY, f32::NEG_INFINITY],
        raw_payload: 0,
        spread: None,
    };
    ctx.entries = vec![fill_entry; ctx.geo.count as usize];
    if opts.spread {
        ctx.spread = Some(SpreadSink::new(out, ctx.entries.len())?);
    }

    let pb = Progress {
        to: opts.progress.as_ref(),
        total: desc.voxel_count(),
    };

    // Levels `0..=top` remain to be built from `input` (the level-`top` volume):
    // in one streaming pass when that fits the bound, else level `top` alone in
    // y-bands (several passes over the input), writing the level `top - 1`
    // volume to a temporary file that becomes the next input.
    let mut top = top;
    let mut owned: Option<brickray_io::RawReader> = None;
    let mut _level_file: Option<PartialFile> = None;
    // The moments of level `top` when it is not the finest (a banded build
    // that records spreads wrote them beside the level's values).
    let mut moments_in: Option<MomentFile> = None;
    let mut cur_plan = first_plan;
    let mut banded = 0u8;
    loop {
        let input: &mut dyn VolumeReader = match owned.as_mut() {
            Some(r) => r,
            None => &mut *reader,
        };
        match cur_plan {
            Plan::Stream { per, .. } => {
                run_stream(&mut ctx, input, moments_in.as_ref(), top, per, &mut w, &pb)?;
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
                let moments_out = if opts.spread {
                    Some(MomentFile::create(out, pdims)?)
                } else {
                    None
                };
                run_bands(
                    &mut ctx,
                    input,
                    top,
                    band_bricks,
                    Files {
                        values: f.file(),
                        path: f.path(),
                        moments_in: moments_in.as_ref(),
                        moments_out: moments_out.as_ref(),
                    },
                    &mut w,
                    &pb,
                )?;
                moments_in = moments_out;
                let pdesc = brickray_core::VolumeDesc {
                    dims: pdims,
                    ..layout.volume.clone()
                };
                owned = Some(brickray_io::RawReader::new(f.path(), 0, pdesc)?);
                _level_file = Some(f);
                top -= 1;
                banded += 1;
                cur_plan = plan(&layout, top, opts.memory_bound, fixed, opts.spread)?;
            }
        }
    }
    if ctx.entries.iter().any(|e| e.level == NO_ENTRY_LEVEL) {
        return Err(StoreError::BadOption {
            option: "input",
            reason: "internal: octree not complete".into(),
        });
    }
    pb.set_position(pb.total);

    // The spread payloads (format version 7) follow the value payloads.
    let payload_end = ctx.offset;
    let spread_entries = match ctx.spread.take() {
        Some(sink) => {
            let n = sink.len;
            let entries = sink.finish(&mut w, payload_end, &tmp_path)?;
            ctx.offset += n;
            Some(entries)
        }
        None => None,
    };
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
    stage::reached("table");
    // The error section (format version 2), computed from the payloads just
    // written; left out when it does not fit the memory bound.
    w.flush().map_err(|e| StoreError::io(&tmp_path, e))?;
    // Label maps record the share of voxels whose label changes instead of
    // value bins (label_errors.rs).
    let compute = if labels {
        label_errors::compute
    } else {
        errors::compute
    };
    let errors = compute(
        tmp.file(),
        &tmp_path,
        &layout,
        &ctx.geo,
        &ctx.entries,
        opts.memory_bound,
    )?;
    let error_bytes = errors
        .as_ref()
        .map(|e| crate::errsec::encode_all(&e.errors));
    if let Some(b) = &error_bytes {
        w.write_all(b).map_err(|e| StoreError::io(&tmp_path, e))?;
    }
    // The parent-error section (format version 3), with its CRC at its end.
    if let Some(e) = &errors {
        let b = crate::errsec::encode_all(&e.parent_errors);
        w.write_all(&b).map_err(|e| StoreError::io(&tmp_path, e))?;
        w.write_all(&crc32fast::hash(&b).to_le_bytes())
            .map_err(|e| StoreError::io(&tmp_path, e))?;
    }
    // The spread table (format version 7), with its CRC at its end.
    let spread_table = spread_entries.as_ref().map(|entries| {
        let mut b = vec![0u8; entries.len() * SPREAD_ENTRY_LEN + 4];
        for (e, c) in entries.iter().zip(b.chunks_exact_mut(SPREAD_ENTRY_LEN)) {
            e.encode(c);
        }
        let n = entries.len() * SPREAD_ENTRY_LEN;
        let crc = crc32fast::hash(&b[..n]);
        b[n..].copy_from_slice(&crc.to_le_bytes());
        b
    });
    if let Some(b) = &spread_table {
        w.write_all(b).map_err(|e| StoreError::io(&tmp_path, e))?;
    }
    // The placement record (format version 6) ends the file.
    if let Some(b) = &placement_bytes {
        w.write_all(b).map_err(|e| StoreError::io(&tmp_path, e))?;
    }
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
        filter: filter_code(filter),
        flags: if opts.empty_below.is_some() {
            FLAG_THRESHOLD
        } else {
            0
        } | if layout.is_isotropic() {
            0
        } else {
            FLAG_SPLIT_MASKS
        } | if error_bytes.is_some() {
            FLAG_ERRORS | FLAG_PARENT_ERRORS
        } else {
            0
        } | if labels { FLAG_LABELS } else { 0 }
            | if placement_bytes.is_some() {
                FLAG_PLACEMENT
            } else {
                0
            }
            | if spread_table.is_some() {
                FLAG_SPREAD
            } else {
                0
            },
        split_masks: layout.split_masks(),
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
        // The value payloads' bytes; the spread payloads follow them.
        payload_bytes: payload_end - HEADER_LEN as u64,
        table_crc: crc32fast::hash(&table),
        errors_crc: error_bytes.as_deref().map_or(0, crc32fast::hash),
    };
    // The header without its magic: until the magic is written, last, the
    // temporary is not a store (`open` refuses it by its name too).
    let mut hb = header.encode();
    hb[..MAGIC.len()].fill(0);
    w.seek(SeekFrom::Start(0))
        .map_err(|e| StoreError::io(&tmp_path, e))?;
    w.write_all(&hb).map_err(|e| StoreError::io(&tmp_path, e))?;
    w.flush().map_err(|e| StoreError::io(&tmp_path, e))?;
    drop(w);
    stage::reached("header");
    tmp.file()
        .sync_all()
        .map_err(|e| StoreError::io(&tmp_path, e))?;
    // Again: the output may have been replaced while the build ran.
    check_output(out, &inputs)?;
    // Everything else is on disk: the magic, synced, then the rename.
    let mut f = tmp.file();
    f.seek(SeekFrom::Start(0))
        .and_then(|_| f.write_all(&MAGIC))
        .and_then(|()| f.sync_data())
        .map_err(|e| StoreError::io(&tmp_path, e))?;
    stage::reached("rename");
    tmp.persist(out)?;
    // The error section, then the parent-error section of the same length
    // and its CRC, then the spread table, then the placement record.
    let file_bytes = table_offset
        + table.len() as u64
        + error_bytes.as_ref().map_or(0, |b| 2 * b.len() as u64 + 4)
        + spread_table.as_ref().map_or(0, |b| b.len() as u64)
        + placement_bytes.as_ref().map_or(0, |b| b.len() as u64);
    Ok(BuildReport {
        layout,
        nodes: ctx.entries.len() as u64,
        data_nodes,
        uniform_nodes,
        empty_nodes,
        input_voxels: desc.voxel_count(),
        input_bytes: desc.byte_len(),
        payload_bytes: payload_end - HEADER_LEN as u64,
        raw_payload_bytes: ctx.raw_payload,
        spread: spread_table.is_some(),
        spread_bytes: table_offset - payload_end,
        file_bytes,
        buffer_estimate: needed,
        banded_levels: banded,
        errors: error_bytes.is_some(),
        placement,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Refuses an output that exists and is not a regular file, or that is one of
/// the build's input files (by file identity).
pub fn check_output(out: &Path, inputs: &[PathBuf]) -> Result<(), StoreError> {
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
    /// Where the spread payloads go (a build that records spreads).
    spread: Option<SpreadSink>,
}
