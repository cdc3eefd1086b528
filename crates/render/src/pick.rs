//! Picking: what lies under a pixel, read back asynchronously like the
//! feedback (a frame or two late, never waited for).
//!
//! [`crate::VolumeRenderer::request_picks`] queues pixels; the next
//! `prepare` copies their depth (the depth the renderer writes: where the
//! ray's opacity reached `RenderSettings::depth_opacity`, or the host's
//! nearer depth) into a read-back ring after its pass, with the frame's
//! camera; [`crate::VolumeRenderer::take_picks`] returns them once mapped,
//! unprojected by [`brickray_core::Camera::unproject`] to volume texture
//! coordinates and world position. The host reads what lies there: a label
//! map's id with `brickray_core::labels::label_at`, an intensity with the
//! volume it holds.

use crate::backend::readback::ReadbackRing;
use crate::error::{PrepareError, RenderError};
use brickray_core::{Camera, VolumeFrame};

/// Most pixels one frame picks.
pub const MAX_PICKS: usize = 4096;
/// Read-back entries (frames whose picks may be in flight at once).
const RING: usize = 3;

/// What lies under a picked pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pick {
    /// The pixel, in the viewport.
    pub pixel: [u32; 2],
    /// The clip depth the renderer wrote there (the far value: nothing).
    pub depth: f32,
    /// The point at that depth: volume texture coordinates (0..1 over the
    /// volume) and world position; `None` where nothing was drawn.
    pub point: Option<PickPoint>,
}

/// A picked point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PickPoint {
    /// Volume texture coordinates (0..1 over the volume's voxels).
    pub texture: [f64; 3],
    /// World position.
    pub world: [f64; 3],
}

/// A ring entry's picks: their pixels and the frame they were drawn in
/// (`None`: the entry holds none).
#[derive(Debug, Default)]
pub(crate) struct PickMeta(Option<PickFrame>);

#[derive(Debug)]
pub(crate) struct PickFrame {
    pixels: Vec<[u32; 2]>,
    camera: Camera,
    frame: VolumeFrame,
    size: [u32; 2],
}

/// Owner of the pick queue and its read-back ring.
pub(crate) struct Picker {
    pending: Vec<[u32; 2]>,
    ring: ReadbackRing<PickMeta>,
    frame: u64,
}

impl std::fmt::Debug for Picker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Picker")
            .field("pending", &self.pending.len())
            .field("frame", &self.frame)
            .finish_non_exhaustive()
    }
}

impl Picker {
    pub(crate) fn new(device: &wgpu::Device) -> Result<Picker, RenderError> {
        Ok(Picker {
            pending: Vec::new(),
            ring: ReadbackRing::new(
                device,
                "brickray-render picks",
                RING,
                (MAX_PICKS * 4) as u64,
            )?,
            frame: 0,
        })
    }

    /// Queues pixels for the next frame (at most [`MAX_PICKS`] in all).
    pub(crate) fn request(&mut self, pixels: &[[u32; 2]]) -> Result<(), PrepareError> {
        if self.pending.len() + pixels.len() > MAX_PICKS {
            return Err(PrepareError::TooManyPicks {
                requested: self.pending.len() + pixels.len(),
                max: MAX_PICKS,
            });
        }
        self.pending.extend_from_slice(pixels);
        Ok(())
    }

    /// After the frame's pass: copies the queued pixels' depth (those
    /// inside the viewport) into a ring entry, with the frame's camera.
    /// Pixels stay queued when no entry is free.
    pub(crate) fn record(
        &mut self,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        depth: &wgpu::Texture,
        camera: Camera,
        frame: VolumeFrame,
        size: [u32; 2],
    ) {
        self.frame += 1;
        if self.pending.is_empty() {
            return;
        }
        let pixels: Vec<[u32; 2]> = self
            .pending
            .iter()
            .copied()
            .filter(|p| p[0] < size[0] && p[1] < size[1])
            .collect();
        let meta = PickMeta(Some(PickFrame {
            pixels: pixels.clone(),
            camera,
            frame,
            size,
        }));
        let recorded = self
            .ring
            .record(queue, encoder, self.frame, meta, |enc, buf, offset| {
                for (i, p) in pixels.iter().enumerate() {
                    enc.copy_texture_to_buffer(
                        wgpu::TexelCopyTextureInfo {
                            texture: depth,
                            mip_level: 0,
                            origin: wgpu::Origin3d {
                                x: p[0],
                                y: p[1],
                                z: 0,
                            },
                            aspect: wgpu::TextureAspect::All,
                        },
                        wgpu::TexelCopyBufferInfo {
                            buffer: buf,
                            layout: wgpu::TexelCopyBufferLayout {
                                offset: offset + 4 * i as u64,
                                bytes_per_row: None,
                                rows_per_image: None,
                            },
                        },
                        wgpu::Extent3d {
                            width: 1,
                            height: 1,
                            depth_or_array_layers: 1,
                        },
                    );
                }
            });
        if recorded {
            self.pending.clear();
        }
    }

    /// The picks read back since the last call, oldest frame first.
    pub(crate) fn take(&mut self) -> Vec<Pick> {
        let done = self.ring.poll(self.frame, |_, meta, payload| {
            let Some(PickFrame {
                pixels,
                camera,
                frame,
                size,
            }) = &meta.0
            else {
                return Vec::new();
            };
            let depths: &[f32] = bytemuck::cast_slice(&payload[..pixels.len() * 4]);
            pixels
                .iter()
                .zip(depths)
                .map(|(&pixel, &depth)| Pick {
                    pixel,
                    depth,
                    point: camera
                        .unproject(frame, *size, pixel, depth)
                        .map(|(texture, world)| PickPoint { texture, world }),
                })
                .collect::<Vec<Pick>>()
        });
        done.into_iter().flat_map(|(_, p)| p).collect()
    }
}
