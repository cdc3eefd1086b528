//! The store's error type.

use brickray_core::{BrickError, NodeKey};
use brickray_io::FileKind;
use brickray_io::IoError;
use std::path::PathBuf;
use thiserror::Error;

/// Errors from building, opening or reading a brick store.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum StoreError {
    /// The operating system refused an operation on the store file.
    #[error("{path}: I/O error: {source}")]
    Io {
        /// The store file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// Reading the input volume failed.
    #[error("input: {0}")]
    Input(#[from] IoError),
    /// The file does not start with the store magic.
    #[error("{path}: not a brickray store (bad magic)")]
    NotAStore {
        /// The file.
        path: PathBuf,
    },
    /// The path names a build's temporary file
    /// (`.<name>.brickray-partial.<pid>-<seq>`): a build in progress, or one
    /// that was killed, never a store, whatever it holds.
    #[error("{path}: a store build's temporary file, not a store")]
    PartialBuild {
        /// The file.
        path: PathBuf,
    },
    /// The file's format version is not one this reader understands.
    #[error("{path}: unsupported store format version {version}")]
    UnsupportedVersion {
        /// The file.
        path: PathBuf,
        /// The version found.
        version: u32,
    },
    /// The file ends before a section it announces.
    #[error("{path}: truncated {section}: needs {needed} bytes, file holds {actual}")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// The section cut short (`header`, `node table`, ...).
        section: &'static str,
        /// Bytes the section needs (end offset).
        needed: u64,
        /// Bytes present.
        actual: u64,
    },
    /// A header field holds an invalid value.
    #[error("{path}: header field `{field}` is invalid: {reason}")]
    BadHeader {
        /// The file.
        path: PathBuf,
        /// The field.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The header checksum does not match.
    #[error("{path}: header checksum mismatch (stored {stored:#010x}, computed {computed:#010x})")]
    HeaderChecksum {
        /// The file.
        path: PathBuf,
        /// The stored checksum.
        stored: u32,
        /// The checksum of the bytes read.
        computed: u32,
    },
    /// The node table checksum does not match.
    #[error(
        "{path}: node table checksum mismatch (stored {stored:#010x}, computed {computed:#010x})"
    )]
    TableChecksum {
        /// The file.
        path: PathBuf,
        /// The stored checksum.
        stored: u32,
        /// The checksum of the bytes read.
        computed: u32,
    },
    /// The error section's checksum does not match (format version 2).
    #[error(
        "{path}: error section checksum mismatch (stored {stored:#010x}, computed {computed:#010x})"
    )]
    ErrorsChecksum {
        /// The file.
        path: PathBuf,
        /// The stored checksum.
        stored: u32,
        /// The checksum of the bytes read.
        computed: u32,
    },
    /// The spread table's checksum does not match (format version 7).
    #[error(
        "{path}: spread table checksum mismatch (stored {stored:#010x}, computed {computed:#010x})"
    )]
    SpreadChecksum {
        /// The file.
        path: PathBuf,
        /// The stored checksum.
        stored: u32,
        /// The checksum of the bytes read.
        computed: u32,
    },
    /// The placement record's checksum does not match (format version 6).
    #[error(
        "{path}: placement record checksum mismatch (stored {stored:#010x}, computed {computed:#010x})"
    )]
    PlacementChecksum {
        /// The file.
        path: PathBuf,
        /// The stored checksum.
        stored: u32,
        /// The checksum of the bytes read.
        computed: u32,
    },
    /// The placement record (format version 6) does not place the volume, or
    /// a build's input gave a placement the record cannot hold: a non-finite
    /// number, voxel axes that do not span space (a singular affine), an
    /// affine whose last row is not `0 0 0 1`, a space other than `RAS`,
    /// `LPS` and `image`, or non-zero reserved bytes.
    #[error("{path}: placement field `{field}` is invalid: {reason}")]
    BadPlacement {
        /// The store file (opening) or the input (building).
        path: PathBuf,
        /// The field: `affine`, `space` or `reserved`.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// A node table entry is invalid.
    #[error("{path}: node {key:?}: table field `{field}` is invalid: {reason}")]
    BadNode {
        /// The file.
        path: PathBuf,
        /// The node whose entry is bad (the key its table slot stands for).
        key: NodeKey,
        /// The field.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// A node's payload does not match its checksum.
    #[error(
        "node {key:?}: payload checksum mismatch (stored {stored:#010x}, computed {computed:#010x})"
    )]
    PayloadChecksum {
        /// The node.
        key: NodeKey,
        /// The stored checksum.
        stored: u32,
        /// The checksum of the bytes read.
        computed: u32,
    },
    /// A node's payload does not decompress to one brick.
    #[error("node {key:?}: payload does not decode: {reason}")]
    Decode {
        /// The node.
        key: NodeKey,
        /// What is wrong.
        reason: String,
    },
    /// Reading a node's payload failed.
    #[error("node {key:?}: I/O error: {source}")]
    NodeIo {
        /// The node.
        key: NodeKey,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The key names no node of this octree.
    #[error("node {key:?} is outside the octree")]
    OutOfRange {
        /// The key.
        key: NodeKey,
    },
    /// A batch read was cancelled: nobody wants its bricks any more.
    #[error("the read was cancelled")]
    Cancelled,
    /// The output buffer has the wrong size.
    #[error("brick buffer holds {actual} bytes, expected {expected}")]
    BufferSize {
        /// Bytes needed.
        expected: usize,
        /// Bytes given.
        actual: usize,
    },
    /// The input holds NaN or infinite samples (f32), first met in this node.
    #[error("input holds NaN or infinite samples (in the voxels of node {key:?})")]
    NonFinite {
        /// The node whose voxels hold the first non-finite sample found.
        key: NodeKey,
    },
    /// Build options are invalid.
    #[error("invalid build option `{option}`: {reason}")]
    BadOption {
        /// The option.
        option: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The build cannot run within the configured memory bound.
    #[error(
        "building needs about {needed} bytes of buffers but the memory bound is {bound} bytes \
         (one brick slab of the input: {slab} bytes); raise the bound or lower the brick size"
    )]
    MemoryBound {
        /// Estimated bytes needed.
        needed: u64,
        /// The configured bound.
        bound: u64,
        /// Bytes of one finest-level brick slab (brick + 2 apron slices).
        slab: u64,
    },
    /// The build's output is one of its input files (the same file, by device
    /// and inode, whatever the spelling: links, `./`, `..`). Nothing was written.
    #[error("output {output} is an input of the build ({input}); refusing to overwrite it")]
    OutputIsInput {
        /// The output as given.
        output: PathBuf,
        /// The input file it is.
        input: PathBuf,
    },
    /// The build's output exists and is not a regular file (a directory, a
    /// FIFO, a device such as `/dev/null`); it is not replaced.
    #[error("output {path} is a {kind}, not a regular file; refusing to replace it")]
    OutputNotRegularFile {
        /// The output.
        path: PathBuf,
        /// What it is.
        kind: FileKind,
    },
    /// The store path names something other than a regular file (found from its
    /// metadata, without opening it: opening a FIFO would block).
    #[error("{path} is a {kind}, not a regular file")]
    NotRegularFile {
        /// The path.
        path: PathBuf,
        /// What it is.
        kind: FileKind,
    },
    /// A procedural region is empty (`lo > hi` on an axis), names a level the
    /// octree does not have, or reaches outside the level volume.
    #[error(
        "region {lo:?}..={hi:?} at level {level} is empty or outside the level volume \
         (level dims {level_dims:?})"
    )]
    RegionOutOfRange {
        /// The level asked for.
        level: u8,
        /// The first voxel asked for.
        lo: [u64; 3],
        /// The last voxel asked for.
        hi: [u64; 3],
        /// The level's dims, `None` when the level does not exist.
        level_dims: Option<[u32; 3]>,
    },
    /// A procedural region holds more voxels than one call evaluates.
    #[error("region of {voxels} voxels is larger than the {max} one call evaluates")]
    RegionTooLarge {
        /// Voxels asked for (saturated at `u64::MAX`).
        voxels: u64,
        /// The limit.
        max: u64,
    },
    /// The build was interrupted: this process is shutting down and has
    /// removed its temporary files ([`crate::remove_partial_files`]).
    #[error("build interrupted: the process is exiting and removed its temporary files")]
    Interrupted,
    /// Bytes of the payload section belong to no data node. The builder writes
    /// the payloads back to back, so a gap means a node's payload reference was
    /// removed or moved (for example a data node forged into a uniform one).
    #[error("{path}: payload bytes {start}..{end} belong to no data node")]
    PayloadGap {
        /// The file.
        path: PathBuf,
        /// First byte of the gap.
        start: u64,
        /// One past its last byte.
        end: u64,
    },
    /// A channel set (`NAME.channels.json`) that cannot be read or whose
    /// stores do not make one multi-channel volume.
    #[error("{path}: channel set: {reason}")]
    ChannelSet {
        /// The channel set's file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Two data nodes' payloads overlap (one node pointed at another's bytes).
    #[error("{path}: node {key:?}'s payload overlaps node {other:?}'s")]
    PayloadOverlap {
        /// The file.
        path: PathBuf,
        /// The node whose payload starts inside another's.
        key: NodeKey,
        /// The node whose payload it overlaps.
        other: NodeKey,
    },
    /// A brick decoded without error (its checksum matches) but contradicts its
    /// node's table entry: a payload that belongs to another node, or a forged
    /// one.
    #[error("node {key:?}: decoded brick contradicts the node table: {mismatch}")]
    BrickMismatch {
        /// The node.
        key: NodeKey,
        /// What disagrees.
        mismatch: Mismatch,
    },
}

/// How a decoded brick contradicts its node's table entry (see
/// [`StoreError::BrickMismatch`]).
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum Mismatch {
    /// A sample is NaN.
    NotANumber {
        /// Index of the first NaN sample in the brick.
        index: usize,
    },
    /// Samples lie outside the node's recorded range.
    OutOfRange {
        /// The recorded minimum.
        min: f32,
        /// The recorded maximum.
        max: f32,
        /// The smallest decoded sample.
        found_min: f32,
        /// The largest decoded sample.
        found_max: f32,
    },
    /// The smallest sample is not the node's recorded `value` (the smallest of
    /// its own stored voxels).
    Smallest {
        /// The recorded value.
        recorded: f32,
        /// The smallest decoded sample.
        found: f32,
    },
    /// A leaf's largest sample is not its recorded maximum (a leaf's range is
    /// exactly the range of its own stored voxels).
    LeafMax {
        /// The recorded maximum.
        recorded: f32,
        /// The largest decoded sample.
        found: f32,
    },
    /// Every sample has the same value: such a node is stored as uniform, never
    /// with a payload.
    Uniform {
        /// The value.
        value: f32,
    },
}

impl std::fmt::Display for Mismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Mismatch::NotANumber { index } => write!(f, "sample {index} is NaN"),
            Mismatch::OutOfRange {
                min,
                max,
                found_min,
                found_max,
            } => write!(
                f,
                "samples span [{found_min}, {found_max}], outside the recorded range [{min}, {max}]"
            ),
            Mismatch::Smallest { recorded, found } => write!(
                f,
                "smallest sample is {found}, the table records {recorded}"
            ),
            Mismatch::LeafMax { recorded, found } => write!(
                f,
                "largest sample of the leaf is {found}, the table records {recorded}"
            ),
            Mismatch::Uniform { value } => write!(
                f,
                "every sample is {value}, but the node is stored with a payload"
            ),
        }
    }
}

impl StoreError {
    pub(crate) fn io(path: &std::path::Path, source: std::io::Error) -> StoreError {
        StoreError::Io {
            path: path.to_owned(),
            source,
        }
    }

    /// Converts into the brick-source error for `key`.
    pub fn into_brick_error(self, key: NodeKey) -> BrickError {
        match self {
            StoreError::OutOfRange { key } => BrickError::OutOfRange { key },
            StoreError::BufferSize { expected, actual } => {
                BrickError::BufferSize { expected, actual }
            }
            StoreError::Cancelled => BrickError::Cancelled { key },
            StoreError::NodeIo { key, source } => BrickError::Io { key, source },
            StoreError::Io { source, .. } => BrickError::Io { key, source },
            other => BrickError::Corrupt {
                key,
                reason: other.to_string(),
            },
        }
    }
}
