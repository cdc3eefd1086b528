//! The rendered image: premultiplied RGBA and clip depth per pixel.

use std::path::Path;

use thiserror::Error;

/// Errors writing an image file.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ImageIoError {
    /// The pixel buffer does not match the dimensions.
    #[error(
        "buffer of {actual} bytes does not hold a {width}x{height} RGBA8 image ({expected} bytes)"
    )]
    SizeMismatch {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Bytes needed.
        expected: usize,
        /// Bytes given.
        actual: usize,
    },
    /// Creating the directory or encoding/writing the PNG failed.
    #[error("writing {path}: {message}")]
    Write {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
}

/// A rendered image, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Premultiplied linear RGBA per pixel, row-major.
    pub color: Vec<[f32; 4]>,
    /// Clip depth per pixel in the camera's convention (standard: 0 near .. 1
    /// far); the far value (1.0 standard, 0.0 reversed-Z) where the ray wrote none.
    pub depth: Vec<f32>,
}

impl Image {
    /// A transparent image with depth 1.0 everywhere.
    pub fn new(width: u32, height: u32) -> Image {
        let n = width as usize * height as usize;
        Image {
            width,
            height,
            color: vec![[0.0; 4]; n],
            depth: vec![1.0; n],
        }
    }

    /// Index of pixel `(x, y)`.
    #[inline]
    fn index(&self, x: u32, y: u32) -> usize {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside {}x{}",
            self.width,
            self.height
        );
        y as usize * self.width as usize + x as usize
    }

    /// Premultiplied RGBA of pixel `(x, y)`.
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 4] {
        self.color[self.index(x, y)]
    }

    /// Clip depth of pixel `(x, y)`.
    pub fn depth_at(&self, x: u32, y: u32) -> f32 {
        self.depth[self.index(x, y)]
    }

    /// Composites over an opaque `background` (`c + (1 - a) * bg`) and converts to
    /// 8-bit with `round(255 * clamp(c, 0, 1))`. Alpha is 255 (the result is
    /// opaque).
    pub fn to_rgba8(&self, background: [f32; 3]) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.color.len() * 4);
        for c in &self.color {
            let a = c[3];
            for k in 0..3 {
                out.push(unorm8(c[k] + (1.0 - a) * background[k]));
            }
            out.push(255);
        }
        out
    }

    /// Reads an 8-bit RGBA image back (for instance from a GPU render target),
    /// interpreting it as premultiplied RGBA (`value / 255`); depth is 1.0.
    /// Rows must be tightly packed (`width * 4` bytes, no alignment padding).
    ///
    /// # Panics
    /// If `rgba.len() != width * height * 4`.
    pub fn from_rgba8(width: u32, height: u32, rgba: &[u8]) -> Image {
        let n = width as usize * height as usize;
        assert_eq!(
            rgba.len(),
            n * 4,
            "RGBA8 buffer does not hold a {width}x{height} image"
        );
        let color = rgba
            .chunks_exact(4)
            .map(|p| std::array::from_fn(|k| p[k] as f32 / 255.0))
            .collect();
        Image {
            width,
            height,
            color,
            depth: vec![1.0; n],
        }
    }

    /// Writes [`to_rgba8`](Image::to_rgba8)`(background)` as an RGBA PNG.
    pub fn save_png(
        &self,
        path: impl AsRef<Path>,
        background: [f32; 3],
    ) -> Result<(), ImageIoError> {
        save_rgba8_png(path, &self.to_rgba8(background), self.width, self.height)
    }
}

/// `round(255 * clamp(c, 0, 1))` (NaN maps to 0).
#[inline]
fn unorm8(c: f32) -> u8 {
    let c = if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) };
    (255.0 * c).round() as u8
}

/// Writes a tightly packed RGBA8 buffer as a PNG, creating the parent directory.
pub fn save_rgba8_png(
    path: impl AsRef<Path>,
    rgba: &[u8],
    width: u32,
    height: u32,
) -> Result<(), ImageIoError> {
    let path = path.as_ref();
    let expected = width as usize * height as usize * 4;
    if rgba.len() != expected {
        return Err(ImageIoError::SizeMismatch {
            width,
            height,
            expected,
            actual: rgba.len(),
        });
    }
    let err = |message: String| ImageIoError::Write {
        path: path.display().to_string(),
        message,
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| err(e.to_string()))?;
    }
    image::save_buffer_with_format(
        path,
        rgba,
        width,
        height,
        image::ExtendedColorType::Rgba8,
        image::ImageFormat::Png,
    )
    .map_err(|e| err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composite_and_round() {
        let mut img = Image::new(2, 1);
        img.color[0] = [0.25, 0.0, 0.5, 0.5];
        img.color[1] = [0.0, 0.0, 0.0, 0.0];
        let b = img.to_rgba8([1.0, 0.0, 0.2]);
        // 0.25 + 0.5 = 0.75 -> 191.25 -> 191; 0 + 0 = 0; 0.5 + 0.1 = 0.6 -> 153.
        assert_eq!(&b[0..4], &[191, 0, 153, 255]);
        // transparent: the background, 0.2 * 255 = 51.
        assert_eq!(&b[4..8], &[255, 0, 51, 255]);
        // over-range premultiplied colour clamps
        img.color[0] = [2.0, -1.0, f32::NAN, 1.0];
        assert_eq!(&img.to_rgba8([0.0; 3])[0..4], &[255, 0, 0, 255]);
    }

    #[test]
    fn rgba8_roundtrip_and_png() {
        let bytes: Vec<u8> = (0..3 * 2 * 4).map(|i| (i * 17 % 256) as u8).collect();
        let img = Image::from_rgba8(3, 2, &bytes);
        assert_eq!(
            img.pixel(1, 1),
            std::array::from_fn(|k| bytes[16 + k] as f32 / 255.0)
        );
        assert_eq!(img.depth_at(2, 1), 1.0);
        // Opaque pixels survive compositing unchanged.
        let opaque: Vec<u8> = bytes
            .chunks(4)
            .flat_map(|p| [p[0].min(200), p[1].min(200), p[2].min(200), 255])
            .collect();
        assert_eq!(Image::from_rgba8(3, 2, &opaque).to_rgba8([0.3; 3]), opaque);

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/x.png");
        Image::from_rgba8(3, 2, &opaque)
            .save_png(&path, [0.0; 3])
            .unwrap();
        let back = image::open(&path).unwrap().into_rgba8();
        assert_eq!(back.dimensions(), (3, 2));
        assert_eq!(back.into_raw(), opaque);
        assert!(matches!(
            save_rgba8_png(&path, &opaque[..4], 3, 2),
            Err(ImageIoError::SizeMismatch { .. })
        ));
    }
}
