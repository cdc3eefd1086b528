//! A reader over a volume already in memory.

use crate::{IoError, VolumeReader, check_slab};
use brickray_core::volume::{Volume, VolumeDesc};
use std::path::{Path, PathBuf};

/// A [`VolumeReader`] over a volume already in memory (for building a brick store
/// from generated data, and for tests).
#[derive(Debug)]
pub struct MemoryReader {
    volume: Volume,
    path: PathBuf,
}

impl MemoryReader {
    /// Wraps a volume; `name` stands for its path in errors.
    pub fn new(volume: Volume, name: impl Into<PathBuf>) -> MemoryReader {
        MemoryReader {
            volume,
            path: name.into(),
        }
    }
}

impl VolumeReader for MemoryReader {
    fn desc(&self) -> &VolumeDesc {
        self.volume.desc()
    }

    fn path(&self) -> &Path {
        &self.path
    }

    /// None: the volume is in memory (its name is not a file).
    fn input_files(&self) -> Vec<PathBuf> {
        Vec::new()
    }

    fn format(&self) -> &'static str {
        "memory"
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        let slice = check_slab(self.volume.desc(), z0, z1, out)? as usize;
        let bytes = self.volume.data().as_bytes();
        out.copy_from_slice(&bytes[z0 as usize * slice..z1 as usize * slice]);
        Ok(())
    }

    fn read_volume(&mut self) -> Result<Volume, IoError> {
        Ok(self.volume.clone())
    }
}
