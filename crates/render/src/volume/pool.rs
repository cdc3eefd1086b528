//! A streamed volume's pool on the GPU: the brick atlas (and the spread and
//! gradient atlases at the same slots), the slot and sub-cell tables, what
//! each slot's brick says of skipping, and the writes of a plan's uploads and
//! fades into them.

use crate::backend::gradients::{self, GradientPass};
use crate::backend::readback::{Outcome, Submission};
use crate::error::RenderError;
use crate::gpu::{self, TableTexture};
use brickray_cache::{FadeSlot, Streamer, Upload};
use brickray_core::NodeKey;

/// `range[3]` of a borrowed slot's row ([`FadeSlot::borrowed`]): above 1,
/// ooc.wgsl draws the leaf from the ancestor alone, at the ancestor's step.
const BORROWED_WEIGHT: f32 = 2.0;

/// `struct SlotInfo` of ooc.wgsl: one row of the slot table. `offset[3]`
/// (levels up to the fade fallback, 0: none), `range[2]` (the fallback's slot)
/// and `range[3]` (its weight) carry a level-of-detail fade ([`FadeSlot`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct SlotInfo {
    pub(crate) offset: [f32; 4],
    pub(crate) range: [f32; 4],
}

/// Texels of one slot-table row (`SlotInfo`: two Rgba32Float texels).
const SLOT_TEXELS: usize = 2;

/// The pool's GPU side, sized by the pool's slot grid: the atlas and the
/// per-slot tables (recreated when the GPU budget changes).
pub(super) struct Pool {
    atlas: wgpu::Texture,
    pub(super) atlas_view: wgpu::TextureView,
    /// Each texel's spread (`R16Float`, the atlas's dims) when the format
    /// carries spreads, else a 1x1x1 stand-in.
    spread: wgpu::Texture,
    pub(super) spread_view: wgpu::TextureView,
    /// The format carries spreads (the spread atlas is not the stand-in).
    spreads: bool,
    /// Each texel's gradient (`gradients::FORMAT`, the atlas's dims) when the
    /// format keeps them ([`brickray_cache::GpuFormat::gradients`]), else a 1x1x1 stand-in;
    /// made on the GPU for each upload by `gradient_pass`.
    _gradients: wgpu::Texture,
    pub(super) gradients_view: wgpu::TextureView,
    gradient_pass: Option<GradientPass>,
    /// The gradient passes recorded into host encoders not known to have run,
    /// with their boxes (atlas offsets): those of an encoder the host
    /// dropped are recorded again into the next frame's
    /// ([`record_gradients`](Pool::record_gradients)).
    gradient_runs: Vec<(Submission, Vec<[u32; 3]>)>,
    /// Boxes (atlas offsets) uploaded, or whose pass was dropped, since the
    /// last frame that drew shaded DVR: their gradients are made by the next
    /// such frame, so a volume drawn unshaded pays no pass.
    gradients_owed: Vec<[u32; 3]>,
    pub(super) atlas_bytes: u64,
    /// The slot table: two Rgba32Float texels a row (`slot_offset` and
    /// `slot_range` in ooc_volume.wgsl).
    pub(super) slots: TableTexture,
    slots_cpu: Vec<SlotInfo>,
    slots_dirty: bool,
    /// Each slot's sub-cell ranges, one Rg32Float texel each (channel after
    /// channel for a multi-channel volume).
    pub(super) sub_cells: TableTexture,
    /// Slots whose rows carry a fade (cleared before the next frame's fades).
    faded: Vec<u32>,
    /// Per slot, of its brick's sub-cells, `[skipped, all]` by MIP's
    /// skipping over axis rays within the brick
    /// (`brickray_core::mip_skip_counts`); `None` for a multi-channel
    /// volume (its MIP always skips).
    mip_cells: Option<Vec<[u64; 2]>>,
    /// Per slot, its brick's sub-cell ranges and how many are transparent
    /// through a transfer function, for DVR's skip rule; `None` for a
    /// multi-channel volume or a label map (they always skip).
    dvr_cells: Option<DvrCells>,
    /// Sub-cells per brick axis.
    sub_cells_per_axis: u32,
}

/// The sub-cell ranges of each slot's brick (kept at upload) and, counted
/// lazily, how many of them are transparent through the transfer function
/// of generation `tf` (`TransferFunction::is_transparent`, the CPU twin of
/// common.wgsl's `tf_transparent`).
struct DvrCells {
    /// Sub-cells per slot.
    per_slot: usize,
    /// `per_slot` ranges per slot, slot after slot.
    ranges: Vec<[f32; 2]>,
    transparent: Vec<u32>,
    /// Slots uploaded since the counts were last brought up to date.
    stale: Vec<u32>,
    /// The generation of the transfer function the counts are under.
    tf: Option<u64>,
}

impl DvrCells {
    fn new(slots: usize, per_slot: usize) -> DvrCells {
        DvrCells {
            per_slot,
            ranges: vec![[0.0, 0.0]; slots * per_slot],
            transparent: vec![0; slots],
            stale: Vec::new(),
            tf: None,
        }
    }

    /// Keeps `slot`'s brick's sub-cell ranges (counted at the next query).
    fn upload(&mut self, slot: u32, cells: &[[f32; 2]]) {
        let at = slot as usize * self.per_slot;
        if let Some(dst) = self.ranges.get_mut(at..at + self.per_slot) {
            let n = cells.len().min(dst.len());
            dst[..n].copy_from_slice(&cells[..n]);
            self.stale.push(slot);
        }
    }

    /// The share of the sub-cells of the bricks in `leaves` transparent
    /// through `tf` (generation `generation`; 0 for no bricks): every slot
    /// counted again when the generation changed, else the slots uploaded
    /// since.
    fn transparent_share(
        &mut self,
        leaves: &[(u32, NodeKey)],
        tf: &brickray_core::TransferFunction,
        generation: u64,
    ) -> f64 {
        let count = |ranges: &[[f32; 2]]| {
            ranges
                .iter()
                .filter(|r| tf.is_transparent(r[0], r[1]))
                .count() as u32
        };
        if self.tf != Some(generation) {
            self.tf = Some(generation);
            self.stale.clear();
            for (t, ranges) in self
                .transparent
                .iter_mut()
                .zip(self.ranges.chunks(self.per_slot.max(1)))
            {
                *t = count(ranges);
            }
        } else {
            for slot in std::mem::take(&mut self.stale) {
                let at = slot as usize * self.per_slot;
                if let (Some(t), Some(ranges)) = (
                    self.transparent.get_mut(slot as usize),
                    self.ranges.get(at..at + self.per_slot),
                ) {
                    *t = count(ranges);
                }
            }
        }
        let transparent: u64 = leaves
            .iter()
            .filter_map(|&(slot, _)| self.transparent.get(slot as usize))
            .map(|&n| n as u64)
            .sum();
        let all = leaves.len() as u64 * self.per_slot as u64;
        if all == 0 {
            0.0
        } else {
            transparent as f64 / all as f64
        }
    }
}

impl Pool {
    pub(super) fn new(
        device: &wgpu::Device,
        streamer: &Streamer,
        format: wgpu::TextureFormat,
    ) -> Result<Pool, RenderError> {
        let gpu = streamer.gpu_format();
        let labels = streamer.layout().volume.kind.is_labels();
        let dims = streamer.pool().atlas_dims();
        let atlas = gpu::sampled_3d(device, dims, format, "brickray-render brick atlas")?;
        let spread_dims = if gpu.spread { dims } else { [1, 1, 1] };
        let spread = gpu::sampled_3d(
            device,
            spread_dims,
            wgpu::TextureFormat::R16Float,
            "brickray-render spread atlas",
        )?;
        let gradients = match gpu.gradients {
            true => gradients::storage_3d(device, dims, "brickray-render gradient atlas")?,
            false => gpu::sampled_3d(
                device,
                [1, 1, 1],
                gradients::FORMAT,
                "brickray-render gradient atlas stand-in",
            )?,
        };
        let gradient_pass = gpu
            .gradients
            .then(|| GradientPass::new(device))
            .transpose()?;
        let atlas_bytes = dims.iter().map(|&d| d as u64).product::<u64>()
            * (gpu.texel_bytes() + gpu.spread_bytes() + gpu.gradient_bytes()) as u64;
        let slot_count = streamer.pool().slot_count().max(1) as u64;
        let rows = streamer.slot_rows() as usize;
        let sub_cells = TableTexture::new(
            device,
            "brickray-render brick sub-cell table",
            wgpu::TextureFormat::Rg32Float,
            (slot_count * (gpu.sub_cells_per_axis as u64).pow(3) * gpu.channel_count as u64)
                as usize,
        )?;
        Ok(Pool {
            atlas_view: atlas.create_view(&Default::default()),
            atlas,
            spread_view: spread.create_view(&Default::default()),
            spread,
            spreads: gpu.spread,
            gradients_view: gradients.create_view(&Default::default()),
            _gradients: gradients,
            gradient_pass,
            gradient_runs: Vec::new(),
            gradients_owed: Vec::new(),
            atlas_bytes,
            slots: Pool::slot_table(device, rows)?,
            slots_cpu: vec![bytemuck::Zeroable::zeroed(); rows],
            slots_dirty: true,
            sub_cells,
            faded: Vec::new(),
            mip_cells: (gpu.channel_count == 1).then(|| vec![[0, 0]; slot_count as usize]),
            dvr_cells: (gpu.channel_count == 1 && !labels).then(|| {
                DvrCells::new(
                    slot_count as usize,
                    (gpu.sub_cells_per_axis as usize).pow(3),
                )
            }),
            sub_cells_per_axis: gpu.sub_cells_per_axis,
        })
    }

    fn slot_table(device: &wgpu::Device, rows: usize) -> Result<TableTexture, RenderError> {
        TableTexture::new(
            device,
            "brickray-render brick slot table",
            wgpu::TextureFormat::Rgba32Float,
            rows * SLOT_TEXELS,
        )
    }

    /// Grows the slot table to the rows the planner needs now (a switch to
    /// octant-granular cuts at run time); the atlas and the pool's slots
    /// stay. True when it was recreated.
    pub(super) fn ensure_rows(
        &mut self,
        device: &wgpu::Device,
        rows: usize,
    ) -> Result<bool, RenderError> {
        if rows <= self.slots_cpu.len() {
            return Ok(false);
        }
        self.slots = Pool::slot_table(device, rows)?;
        self.slots_cpu.resize(rows, bytemuck::Zeroable::zeroed());
        self.slots_dirty = true;
        Ok(true)
    }

    /// Writes this frame's uploads, prepared by the loader threads: texels into
    /// the atlas, sub-cell ranges and slot rows into their tables; then the
    /// rows of fading and borrowed leaves. Returns the bytes written. (Their
    /// gradients, where the format keeps them: [`record_gradients`](Pool::record_gradients).)
    pub(super) fn write(
        &mut self,
        queue: &wgpu::Queue,
        uploads: &[Upload],
        fades: &[FadeSlot],
        side: u32,
        bpp: u32,
    ) -> u64 {
        let mut bytes = 0u64;
        for up in uploads {
            bytes += self.write_upload(queue, up, side, bpp);
        }
        // Fades: last frame's cleared, this frame's set (after the uploads,
        // which reset their slots' rows).
        for slot in std::mem::take(&mut self.faded) {
            if let Some(s) = self.slots_cpu.get_mut(slot as usize) {
                s.offset[3] = 0.0;
                s.range[2] = 0.0;
                s.range[3] = 0.0;
                self.slots_dirty = true;
            }
        }
        for f in fades {
            self.write_fade(f);
        }
        if self.slots_dirty {
            self.slots
                .write_at(queue, 0, bytemuck::cast_slice(&self.slots_cpu));
            bytes += std::mem::size_of_val(self.slots_cpu.as_slice()) as u64;
            self.slots_dirty = false;
        }
        bytes
    }

    /// Where the format keeps gradients, and `wanted` (a view draws shaded
    /// DVR this frame), records into `encoder` the pass that makes the
    /// gradients of this frame's `uploads` (`side`^3 texels each,
    /// `scale_offset` mapping texels to normalized values), of the bricks
    /// uploaded since the last such frame, and of those whose pass went into
    /// an encoder the host dropped unsubmitted (the queue's writes of their
    /// texels landed all the same; a slot uploaded again since holds a newer
    /// brick, whose gradients the pass then makes once more). Otherwise it
    /// only notes what it owes. Called every frame, with or without a plan,
    /// so that no submitted frame samples a brick whose gradients were never
    /// made.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn record_gradients(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        uploads: &[Upload],
        wanted: bool,
        side: u32,
        scale_offset: [f32; 2],
    ) -> Result<(), RenderError> {
        let Some(pass) = self.gradient_pass.as_mut() else {
            return Ok(());
        };
        let owed = &mut self.gradients_owed;
        owed.extend(uploads.iter().map(|u| u.atlas_offset));
        self.gradient_runs
            .retain_mut(|(run, dropped)| match run.outcome() {
                Outcome::Pending => true,
                Outcome::Ran => false,
                Outcome::Dropped => {
                    owed.append(dropped);
                    false
                }
            });
        // Each box once (a slot uploaded again while owed is listed twice):
        // before a pass, and whenever the list outgrows twice the slots.
        if wanted || owed.len() > 2 * self.slots_cpu.len() {
            owed.sort_unstable();
            owed.dedup();
        }
        if !wanted || owed.is_empty() {
            return Ok(());
        }
        let boxes = std::mem::take(owed);
        let recorded = pass.record(
            device,
            queue,
            encoder,
            &self.atlas_view,
            &self.gradients_view,
            [side; 3],
            scale_offset,
            &boxes,
        );
        // A pass that could not be recorded is tried again next frame.
        let run = match recorded {
            Ok(()) => Submission::watch(encoder),
            Err(_) => Submission::dropped(),
        };
        self.gradient_runs.push((run, boxes));
        recorded
    }

    /// Of the sub-cells of the bricks in `leaves` (`(slot, node)`), the
    /// share MIP's skipping is certain to skip within each brick; `None` for
    /// a multi-channel volume, and 0 for no bricks.
    pub(super) fn mip_skip_share(&self, leaves: &[(u32, NodeKey)]) -> Option<f64> {
        let cells = self.mip_cells.as_ref()?;
        let [skipped, all] = leaves
            .iter()
            .filter_map(|&(slot, _)| cells.get(slot as usize))
            .fold([0u64; 2], |a, c| [a[0] + c[0], a[1] + c[1]]);
        Some(if all == 0 {
            0.0
        } else {
            skipped as f64 / all as f64
        })
    }

    /// True when the slots' transparent sub-cells are counted (a
    /// single-channel intensity volume).
    pub(super) fn counts_dvr_cells(&self) -> bool {
        self.dvr_cells.is_some()
    }

    /// Of the sub-cells of the bricks in `leaves`, the share transparent
    /// through `tf` (of generation `generation`); `None` where they are not
    /// counted.
    pub(super) fn dvr_transparent_share(
        &mut self,
        leaves: &[(u32, NodeKey)],
        tf: &brickray_core::TransferFunction,
        generation: u64,
    ) -> Option<f64> {
        let d = self.dvr_cells.as_mut()?;
        Some(d.transparent_share(leaves, tf, generation))
    }

    fn write_upload(&mut self, queue: &wgpu::Queue, up: &Upload, side: u32, bpp: u32) -> u64 {
        let b = &up.brick;
        write_brick(queue, &self.atlas, up.atlas_offset, &b.texels, side, bpp);
        let mut spread_bytes = 0;
        if let Some(s) = b.spread.as_deref().filter(|_| self.spreads) {
            let bytes: &[u8] = bytemuck::cast_slice(s);
            write_brick(queue, &self.spread, up.atlas_offset, bytes, side, 2);
            spread_bytes = bytes.len() as u64;
        }
        let cells: &[u8] = bytemuck::cast_slice(&b.sub_cells);
        let per_slot = b.sub_cells.len();
        self.sub_cells
            .write_at(queue, up.slot as usize * per_slot, cells);
        if let Some(m) = self
            .mip_cells
            .as_mut()
            .and_then(|m| m.get_mut(up.slot as usize))
        {
            let n = self.sub_cells_per_axis;
            *m = brickray_core::mip_skip_counts([n; 3], &b.sub_cells);
        }
        if let Some(d) = self.dvr_cells.as_mut() {
            d.upload(up.slot, &b.sub_cells);
        }
        if let Some(s) = self.slots_cpu.get_mut(up.slot as usize) {
            let o = up.atlas_offset;
            *s = SlotInfo {
                offset: [o[0] as f32, o[1] as f32, o[2] as f32, 0.0],
                range: [b.range[0], b.range[1], 0.0, 0.0],
            };
            self.slots_dirty = true;
        }
        (b.texels.len() + cells.len()) as u64 + spread_bytes
    }

    fn write_fade(&mut self, f: &FadeSlot) {
        // A borrowed slot's row is its ancestor's (offset, range), drawn
        // from the ancestor alone: weight 2 tells ooc.wgsl.
        let row = if f.borrowed {
            let Some(&lender) = self.slots_cpu.get(f.fallback as usize) else {
                return;
            };
            SlotInfo {
                offset: [lender.offset[0], lender.offset[1], lender.offset[2], 0.0],
                range: [lender.range[0], lender.range[1], 0.0, 0.0],
            }
        } else {
            match self.slots_cpu.get(f.slot as usize) {
                Some(&s) => s,
                None => return,
            }
        };
        if let Some(s) = self.slots_cpu.get_mut(f.slot as usize) {
            *s = row;
            s.offset[3] = f.levels_up as f32;
            s.range[2] = f.fallback as f32;
            s.range[3] = if f.borrowed {
                BORROWED_WEIGHT
            } else {
                f.weight
            };
            self.faded.push(f.slot);
            self.slots_dirty = true;
        }
    }
}

/// Writes one brick's texels (`side^3` of `bpp` bytes, x fastest) into
/// `texture` at `offset`.
fn write_brick(
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    offset: [u32; 3],
    texels: &[u8],
    side: u32,
    bpp: u32,
) {
    queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d {
                x: offset[0],
                y: offset[1],
                z: offset[2],
            },
            aspect: wgpu::TextureAspect::All,
        },
        texels,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(side * bpp),
            rows_per_image: Some(side),
        },
        wgpu::Extent3d {
            width: side,
            height: side,
            depth_or_array_layers: side,
        },
    );
}
