//! The reader seam: what a reader describes ([`VolumeReader`]), where the
//! volume lies in the world ([`Placement`]), and what a caller chooses
//! ([`ReadOptions`]).

use crate::IoError;
use brickray_core::VolumeFrame;
use brickray_core::volume::{Volume, VolumeData, VolumeDesc, VolumeError};
use std::path::{Path, PathBuf};

/// Options of the readers ([`open_with`](crate::open_with), [`RawReader::open_sidecar_with`](crate::RawReader::open_sidecar_with),
/// [`NrrdReader::open_with`](crate::NrrdReader::open_with), ...): safety switches and which part of a
/// multi-part input to read. The default is strict and reads the default part
/// (the largest DICOM series, the finest OME-Zarr level, the first channel and
/// time point).
#[derive(Debug, Clone, Default, PartialEq)]
#[non_exhaustive]
pub struct ReadOptions {
    /// Let a sidecar's `file`, a NRRD header's `data file` or a NIfTI header's
    /// `.img` name a file outside the header's folder (absolute paths, `..`,
    /// symbolic links leading out). Off by default: a header from elsewhere
    /// cannot make the reader read any file the process can read.
    pub allow_outside_dir: bool,
    /// The DICOM series to read (its SeriesInstanceUID, or its index in
    /// [`Registry::list`](crate::Registry::list)'s order); `None`: the series with the most slices.
    pub series: Option<String>,
    /// The OME-Zarr multiscale level (0 = finest); `None`: 0.
    pub level: Option<usize>,
    /// The channel of a multi-channel input; `None`: the first.
    pub channel: Option<u64>,
    /// The channels [`read_channels`](crate::read_channels) reads (indices
    /// in the file, at most [`brickray_core::MAX_CHANNELS`], in this order);
    /// `None`: every channel (an error beyond the maximum). The
    /// single-channel reads use [`channel`](Self::channel) instead.
    pub channels: Option<Vec<u64>>,
    /// The time point of a time series; `None`: the first.
    pub time: Option<u64>,
    /// The voxel spacing to use where the file states none (a plain TIFF);
    /// `None`: 1, 1, 1 there. Formats that state a spacing keep theirs.
    pub spacing: Option<[f32; 3]>,
}

impl ReadOptions {
    /// Sets [`ReadOptions::allow_outside_dir`].
    pub fn allow_outside_dir(mut self, allow: bool) -> ReadOptions {
        self.allow_outside_dir = allow;
        self
    }
    /// Sets [`ReadOptions::series`].
    pub fn series(mut self, series: Option<String>) -> ReadOptions {
        self.series = series;
        self
    }
    /// Sets [`ReadOptions::level`].
    pub fn level(mut self, level: Option<usize>) -> ReadOptions {
        self.level = level;
        self
    }
    /// Sets [`ReadOptions::channel`].
    pub fn channel(mut self, channel: Option<u64>) -> ReadOptions {
        self.channel = channel;
        self
    }
    /// Sets [`ReadOptions::channels`].
    pub fn channels(mut self, channels: Option<Vec<u64>>) -> ReadOptions {
        self.channels = channels;
        self
    }
    /// Sets [`ReadOptions::spacing`].
    pub fn spacing(mut self, spacing: Option<[f32; 3]>) -> ReadOptions {
        self.spacing = spacing;
        self
    }
    /// Sets [`ReadOptions::time`].
    pub fn time(mut self, time: Option<u64>) -> ReadOptions {
        self.time = time;
        self
    }
}

/// Where a volume lies in the world, as its file states it: the affine map
/// from voxel indices (`i, j, k`, voxel centres at integers; `i` along x of
/// [`VolumeDesc::dims`]) to world coordinates (for medical formats, patient
/// millimetres in RAS+ or LPS+ as [`Placement::space`] says).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Row-major 4x4 voxel-to-world affine (last row `0 0 0 1`).
    pub affine: [[f64; 4]; 4],
    /// The world's axes: `"RAS"` (NIfTI), `"LPS"` (DICOM) or `"image"` (a
    /// microscope's stage axes: OME-Zarr, TIFF).
    pub space: &'static str,
}

impl Placement {
    /// A scale-and-translate placement (no rotation): voxel `i` along axis `a`
    /// lies at `origin[a] + i * spacing[a]`.
    pub fn axis_aligned(spacing: [f64; 3], origin: [f64; 3], space: &'static str) -> Placement {
        let mut affine = [[0.0; 4]; 4];
        for a in 0..3 {
            affine[a][a] = spacing[a];
            affine[a][3] = origin[a];
        }
        affine[3][3] = 1.0;
        Placement { affine, space }
    }

    /// The voxel-to-world matrix as a column-major [`glam::DMat4`].
    pub fn matrix(&self) -> glam::DMat4 {
        glam::DMat4::from_cols_array_2d(&self.affine).transpose()
    }

    /// The world position of voxel `(i, j, k)`.
    pub fn voxel_to_world(&self, ijk: [f64; 3]) -> [f64; 3] {
        self.matrix()
            .transform_point3(glam::DVec3::from_array(ijk))
            .to_array()
    }

    /// The voxel-to-patient matrix in RAS+ (an LPS+ placement with its first
    /// two rows negated), or `None` when the placement is not anatomical
    /// (`"image"`: a microscope's stage axes).
    pub fn voxel_to_ras(&self) -> Option<glam::DMat4> {
        let flip = match self.space {
            "RAS" => glam::DVec4::ONE,
            "LPS" => glam::DVec4::new(-1.0, -1.0, 1.0, 1.0),
            _ => return None,
        };
        Some(glam::DMat4::from_diagonal(flip) * self.matrix())
    }

    /// The volume's anatomical orientation (its axis code, display frame,
    /// views and slices: [`brickray_core::anatomy`]), or `None` when the
    /// placement is not anatomical or cannot orient (a singular matrix).
    pub fn orientation(&self) -> Option<brickray_core::anatomy::Orientation> {
        brickray_core::anatomy::Orientation::new(self.voxel_to_ras()?).ok()
    }

    /// The [`VolumeFrame`] that puts the volume's texture space `[0,1]^3` where
    /// this placement says (voxel `i` is at texture coordinate `(i + 0.5) / n`),
    /// so that a mirrored or rotated acquisition is shown as acquired.
    pub fn frame(&self, dims: [u32; 3]) -> VolumeFrame {
        let d = glam::DVec3::from_array(dims.map(f64::from));
        let tex_to_voxel =
            glam::DMat4::from_translation(glam::DVec3::splat(-0.5)) * glam::DMat4::from_scale(d);
        VolumeFrame::new((self.matrix() * tex_to_voxel).as_mat4(), dims)
    }
}

/// A source of volume samples that can be streamed slab by slab.
pub trait VolumeReader: Send {
    /// The volume's description. Its `value_range` is the file's declared range,
    /// or the data's min..max when the file declares none.
    fn desc(&self) -> &VolumeDesc;

    /// Reads slices `z0..z1` as little-endian samples into `out`, whose length must
    /// be `(z1 - z0) * nx * ny * dtype.size()` (else [`IoError::SlabBuffer`]). Reading slabs in increasing z is
    /// always efficient; other orders may re-read compressed inputs.
    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError>;

    /// The path that names this input in errors: a file, or a folder for the
    /// formats that are folders (a DICOM series, TIFF slices, OME-Zarr).
    fn path(&self) -> &Path;

    /// The format's name (`"raw"`, `"NRRD"`, `"NIfTI-1"`, `"DICOM"`, ...).
    fn format(&self) -> &'static str {
        "raw"
    }

    /// Where the file places the volume in the world, if it says (NIfTI's
    /// qform/sform, DICOM's patient position and orientation, OME-Zarr's
    /// coordinate transformations). `None`: only [`VolumeDesc::spacing`] is
    /// known.
    fn placement(&self) -> Option<Placement> {
        None
    }

    /// What the reader noticed and the user should know (a conversion of the
    /// sample type, a gantry tilt, non-uniform slice spacing, ...), one line each.
    fn notes(&self) -> Vec<String> {
        Vec::new()
    }

    /// What the reader had to assume because the file did not say, or said
    /// something unusable where the format's readers customarily fall back
    /// (a DICOM slice without PixelSpacing read at 1 mm, a TIFF without
    /// spacing read at 1, 1, 1, a NIfTI `scl_slope` that is not finite read
    /// as no rescale, ...), one line each. Empty when the volume is as the
    /// file states it. A caller should show these to the user (the
    /// command-line tools print them, the viewer shows them): a value that is
    /// invalid and has no customary fallback is an error instead, never a
    /// silent default.
    fn warnings(&self) -> Vec<String> {
        Vec::new()
    }

    /// Every file this reader reads (header or sidecar, and data file; each
    /// slice of a folder), so that a caller writing a file can refuse to
    /// overwrite one of its inputs. The default is [`path`](Self::path).
    fn input_files(&self) -> Vec<PathBuf> {
        vec![self.path().to_owned()]
    }

    /// Reads the whole volume, validating it (NaN/Inf samples are an error).
    fn read_volume(&mut self) -> Result<Volume, IoError> {
        let desc = self.desc().clone();
        let len = usize::try_from(desc.byte_len()).map_err(|_| {
            IoError::volume(
                self.path(),
                VolumeError::BadDims {
                    dims: desc.dims.map(u64::from),
                    max: brickray_core::volume::MAX_DIM,
                },
            )
        })?;
        let mut bytes = vec![0u8; len];
        self.read_slices(0, desc.dims[2], &mut bytes)?;
        let data = VolumeData::from_le_bytes(desc.dtype, &bytes);
        Volume::new(desc, data).map_err(|e| IoError::volume(self.path(), e))
    }
}
