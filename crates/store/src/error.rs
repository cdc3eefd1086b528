//! The store's error type.

use brickray_core::{BrickError, IoError, NodeKey};
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
            StoreError::NodeIo { key, source } => BrickError::Io { key, source },
            StoreError::Io { source, .. } => BrickError::Io { key, source },
            other => BrickError::Corrupt {
                key,
                reason: other.to_string(),
            },
        }
    }
}
