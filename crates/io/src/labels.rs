//! Reading any volume as a label map ([`AsLabels`]): the explicit open
//! option of formats whose files do not say (a NIfTI atlas, a TIFF of
//! instance ids).

use crate::error::IoError;
use crate::reader::{Placement, VolumeReader};
use brickray_core::{VolumeDesc, VolumeKind};
use std::path::{Path, PathBuf};

/// A reader whose volume is declared a label map
/// ([`VolumeKind::Labels`], the label value range of
/// `brickray_core::labels`); the samples are the inner reader's, unchanged.
pub struct AsLabels {
    inner: Box<dyn VolumeReader>,
    desc: VolumeDesc,
}

impl std::fmt::Debug for AsLabels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AsLabels")
            .field("desc", &self.desc)
            .finish_non_exhaustive()
    }
}

impl AsLabels {
    /// Declares `inner`'s volume a label map. Its samples must be u8, u16 or
    /// u32 ([`IoError::Volume`] with `VolumeError::LabelType` otherwise).
    pub fn new(inner: Box<dyn VolumeReader>) -> Result<AsLabels, IoError> {
        let desc = VolumeDesc {
            kind: VolumeKind::Labels,
            value_range: brickray_core::labels::label_value_range(),
            ..inner.desc().clone()
        };
        desc.validate()
            .map_err(|e| IoError::volume(inner.path(), e))?;
        Ok(AsLabels { inner, desc })
    }
}

impl VolumeReader for AsLabels {
    fn desc(&self) -> &VolumeDesc {
        &self.desc
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        self.inner.read_slices(z0, z1, out)
    }

    fn path(&self) -> &Path {
        self.inner.path()
    }

    fn format(&self) -> &'static str {
        self.inner.format()
    }

    fn placement(&self) -> Option<Placement> {
        self.inner.placement()
    }

    fn notes(&self) -> Vec<String> {
        self.inner.notes()
    }

    fn warnings(&self) -> Vec<String> {
        self.inner.warnings()
    }

    fn input_files(&self) -> Vec<PathBuf> {
        self.inner.input_files()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MemoryReader;
    use brickray_core::{DType, Volume, VolumeData};

    fn reader(data: VolumeData) -> Box<dyn VolumeReader> {
        let vol = Volume::with_data_range([2, 1, 1], [1.0; 3], data).unwrap();
        Box::new(MemoryReader::new(vol, "memory"))
    }

    #[test]
    fn integer_volumes_become_label_maps() {
        let mut r = AsLabels::new(reader(VolumeData::U8(vec![3, 9]))).unwrap();
        assert!(r.desc().kind.is_labels());
        let v = r.read_volume().unwrap();
        assert_eq!(v.data(), &VolumeData::U8(vec![3, 9]));
        assert_eq!(v.desc().dtype, DType::U8);
    }

    #[test]
    fn float_volumes_are_refused() {
        let e = AsLabels::new(reader(VolumeData::F32(vec![0.5, 1.0])))
            .expect_err("f32 is not a label type");
        assert!(e.to_string().contains("u8, u16 or u32"), "{e}");
    }
}
