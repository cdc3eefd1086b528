//! Label maps: volumes whose voxels hold integer ids of a segmentation
//! ([`VolumeKind::Labels`]).
//!
//! A label id is never filtered or averaged: it is read at the nearest voxel,
//! coarser levels take the most frequent label of their children
//! ([`mode_of`], ties to the smallest id, so a coarse level holds no label the
//! finer data lacks), and it is drawn through a [`LabelTable`] (per label
//! colour, opacity and visibility, a selection and a hover highlight) turned
//! into an exact per-label transfer function ([`LabelTable::to_transfer_function`]):
//! label `i` maps to normalized value `i / (LABEL_TABLE_ENTRIES - 1)`
//! ([`label_value_range`]), the centre of table entry `i`, so a nearest
//! sample looks up its own label's entry and nothing else, and the TF's
//! opacity prefix sums answer "are all labels of this brick hidden?" for
//! empty-space skipping as they do for intensities.
//!
//! Ids must be below [`LABEL_TABLE_ENTRIES`] to be drawn; an in-memory volume
//! with larger ids is renumbered densely ([`relabel_dense`]).

use crate::tf::TransferFunction;
use crate::volume::{DType, Volume, VolumeData, VolumeDesc, VolumeError, VolumeKind};
use std::collections::{BTreeMap, BTreeSet};
use thiserror::Error;

/// Entries of a label table: ids `0..LABEL_TABLE_ENTRIES` are drawn (2048:
/// every such id is exact in a half-float texel, the one label texel format
/// every device can sample).
pub const LABEL_TABLE_ENTRIES: usize = 2048;

/// The value range of a label volume: label `i` normalizes to
/// `i / (LABEL_TABLE_ENTRIES - 1)`, the centre of label-table entry `i`.
pub const fn label_value_range() -> [f32; 2] {
    [0.0, (LABEL_TABLE_ENTRIES - 1) as f32]
}

/// Errors of label maps and label tables.
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum LabelError {
    /// A label id beyond what the label table draws.
    #[error(
        "label id {id} is beyond the {max} ids a label table draws; renumber the labels (in memory: brickray_core::labels::relabel_dense)"
    )]
    IdTooLarge {
        /// The id.
        id: u64,
        /// Ids drawn (`LABEL_TABLE_ENTRIES`).
        max: usize,
    },
    /// More distinct labels than the table holds.
    #[error("{count} distinct labels: a label table draws at most {max}")]
    TooManyLabels {
        /// Distinct labels.
        count: usize,
        /// Most drawn.
        max: usize,
    },
    /// The volume cannot hold labels.
    #[error(transparent)]
    Volume(#[from] VolumeError),
    /// A colour-table file that cannot be read.
    #[error("colour table: {0}")]
    Table(String),
}

/// The most frequent value of `v`, ties broken to the smallest value (the
/// filter of coarser label levels). `v` is reordered. Panics on an empty
/// slice.
pub fn mode_of<T: Copy + Ord>(v: &mut [T]) -> T {
    v.sort_unstable();
    let mut best = v[0];
    let mut best_n = 0usize;
    let mut i = 0;
    while i < v.len() {
        let mut j = i + 1;
        while j < v.len() && v[j] == v[i] {
            j += 1;
        }
        // Strictly more: the first (smallest) of equal counts wins.
        if j - i > best_n {
            best_n = j - i;
            best = v[i];
        }
        i = j;
    }
    best
}

/// A label volume from integer data: kind [`VolumeKind::Labels`] and the
/// label value range. Ids at or beyond [`LABEL_TABLE_ENTRIES`] are an error
/// (see [`relabel_dense`]).
pub fn label_volume(
    dims: [u32; 3],
    spacing: [f32; 3],
    data: VolumeData,
) -> Result<Volume, LabelError> {
    let desc = VolumeDesc {
        dims,
        dtype: data.dtype(),
        spacing,
        value_range: label_value_range(),
        kind: VolumeKind::Labels,
    };
    desc.validate()?;
    let vol = Volume::new(desc, data)?;
    check_ids(&vol)?;
    Ok(vol)
}

/// Makes `volume` a label volume (kind and value range), checking its type
/// and ids.
pub fn into_labels(volume: Volume) -> Result<Volume, LabelError> {
    let desc = volume.desc().clone();
    let data = volume.data().clone();
    label_volume(desc.dims, desc.spacing, data)
}

fn check_ids(vol: &Volume) -> Result<(), LabelError> {
    if let Some((_, hi)) = vol.data().min_max()
        && hi as u64 >= LABEL_TABLE_ENTRIES as u64
    {
        return Err(LabelError::IdTooLarge {
            id: hi as u64,
            max: LABEL_TABLE_ENTRIES,
        });
    }
    Ok(())
}

/// Renumbers the labels of `volume` to `0..n` in increasing order of id (0
/// stays 0 when present) and returns the label volume with the original id
/// of each new one (`ids[new] = old`), for volumes whose ids exceed the
/// table. More than [`LABEL_TABLE_ENTRIES`] distinct labels is an error.
pub fn relabel_dense(volume: &Volume) -> Result<(Volume, Vec<u32>), LabelError> {
    let data = volume.data();
    let n = data.len();
    let set: BTreeSet<u32> = (0..n).map(|i| data.label(i)).collect();
    if set.len() > LABEL_TABLE_ENTRIES {
        return Err(LabelError::TooManyLabels {
            count: set.len(),
            max: LABEL_TABLE_ENTRIES,
        });
    }
    let ids: Vec<u32> = set.into_iter().collect();
    let index: BTreeMap<u32, u16> = ids
        .iter()
        .enumerate()
        .map(|(i, &id)| (id, i as u16))
        .collect();
    let out: Vec<u16> = (0..n).map(|i| index[&data.label(i)]).collect();
    let d = volume.desc();
    let vol = label_volume(d.dims, d.spacing, VolumeData::U16(out))?;
    Ok((vol, ids))
}

/// The label of the voxel at volume texture coordinates `tex` (0..1 over the
/// volume, the nearest voxel, clamped to the grid): what a pick lands on.
pub fn label_at(volume: &Volume, tex: [f64; 3]) -> u32 {
    let d = volume.dims();
    let i = [0, 1, 2].map(|a| ((tex[a] * d[a] as f64).floor() as i64).clamp(0, d[a] as i64 - 1));
    let [nx, ny, _] = d.map(|v| v as i64);
    volume
        .data()
        .label((i[0] + nx * (i[1] + ny * i[2])) as usize)
}

/// The label at volume texture coordinates `tex` of a label map streamed
/// from `source` (the finest level's voxel, clamped to the grid, as
/// [`label_at`] reads an in-memory volume): reads the one finest brick that
/// holds it. What a pick names on a streamed label map.
pub fn label_at_source(
    source: &dyn crate::BrickSource,
    tex: [f64; 3],
) -> Result<u32, crate::BrickError> {
    let layout = source.layout();
    let finest = layout.levels.saturating_sub(1);
    let d = layout.level_dims(finest);
    let i =
        [0, 1, 2].map(|a| ((tex[a] * d[a] as f64).floor() as i64).clamp(0, d[a] as i64 - 1) as u32);
    let b = layout.brick;
    let key = crate::NodeKey {
        level: finest,
        x: i[0] / b,
        y: i[1] / b,
        z: i[2] / b,
    };
    let mut buf = vec![0u8; layout.brick_bytes()];
    source.read_brick(key, &mut buf)?;
    let side = layout.stored_side() as usize;
    let a = layout.apron as usize;
    let at = [0, 1, 2].map(|k| (i[k] % b) as usize + a);
    let size = layout.dtype().size();
    let start = (at[0] + side * (at[1] + side * at[2])) * size;
    Ok(VolumeData::from_le_bytes(layout.dtype(), &buf[start..start + size]).label(0))
}

/// The 8 voxels around continuous voxel coordinates `p` (voxel centres at
/// integers, clamped to the grid) in the order x fastest, then y, then z:
/// their labels, and the fractions `t` of `p` between them.
fn corners(volume: &Volume, p: [f64; 3]) -> ([u32; 8], [f64; 3]) {
    let f = p.map(f64::floor);
    let t = [p[0] - f[0], p[1] - f[1], p[2] - f[2]];
    let d = volume.dims().map(|v| v as i64);
    let ids = std::array::from_fn(|c| {
        let o = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
        let i = [0, 1, 2].map(|a| (f[a] as i64 + o[a] as i64).clamp(0, d[a] - 1));
        volume
            .data()
            .label((i[0] + d[0] * (i[1] + d[1] * i[2])) as usize)
    });
    (ids, t)
}

/// The trilinear weight of corner `c` at fractions `t`, and its derivative
/// along each axis.
fn corner_weight(c: usize, t: [f64; 3]) -> (f64, [f64; 3]) {
    let o = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
    let w = [0, 1, 2].map(|a| if o[a] == 1 { t[a] } else { 1.0 - t[a] });
    let s = [0, 1, 2].map(|a| if o[a] == 1 { 1.0 } else { -1.0 });
    (
        w[0] * w[1] * w[2],
        [s[0] * w[1] * w[2], s[1] * w[0] * w[2], s[2] * w[0] * w[1]],
    )
}

/// The label with the largest trilinear weight among the 8 corners, ties
/// to the first corner's label.
fn heaviest(ids: &[u32; 8], t: [f64; 3]) -> u32 {
    let mut best = (ids[0], -1.0);
    for c in 0..8 {
        let total: f64 = (0..8)
            .filter(|&k| ids[k] == ids[c])
            .map(|k| corner_weight(k, t).0)
            .sum();
        if total > best.1 {
            best = (ids[c], total);
        }
    }
    best.0
}

/// The label with the largest trilinear weight among the 8 voxels around
/// continuous voxel coordinates `p` (voxel centres at integers, clamped to
/// the grid): the label whose filtered indicator is largest there, ties to
/// the first corner's label in the order x fastest, then y, then z. A label
/// map's smooth boundaries (`RenderSettings::smooth_labels`); the kernels
/// compute the same.
pub fn smooth_label_at(volume: &Volume, p: [f64; 3]) -> u32 {
    let (ids, t) = corners(volume, p);
    heaviest(&ids, t)
}

/// [`smooth_label_at`]'s label and the gradient, per voxel along each axis,
/// of its trilinearly filtered indicator at `p`: the normal of the smooth
/// boundary that shades it (zero inside a region of one label). The kernels
/// compute the same (`label_gradient` in modes.wgsl).
pub fn smooth_label_gradient(volume: &Volume, p: [f64; 3]) -> (u32, [f64; 3]) {
    let (ids, t) = corners(volume, p);
    let label = heaviest(&ids, t);
    let mut g = [0.0; 3];
    for (c, &id) in ids.iter().enumerate() {
        if id == label {
            let (_, d) = corner_weight(c, t);
            for a in 0..3 {
                g[a] += d[a];
            }
        }
    }
    (label, g)
}

/// The labels present in a label volume, in increasing order.
pub fn labels_present(volume: &Volume) -> Vec<u32> {
    let data = volume.data();
    let set: BTreeSet<u32> = (0..data.len()).map(|i| data.label(i)).collect();
    set.into_iter().collect()
}

/// Halves a label volume along every axis by the mode of each 2x2x2 block
/// ([`mode_of`]; a block cut by an odd edge repeats its last voxels, as the
/// store's builder does): the CPU twin of a label store's coarser level.
pub fn downsample_mode(volume: &Volume) -> Volume {
    let [nx, ny, nz] = volume.dims();
    let [px, py, pz] = [nx, ny, nz].map(|d| d.div_ceil(2).max(1));
    let data = volume.data();
    let at = |x: u32, y: u32, z: u32| {
        data.label((x.min(nx - 1) + nx * (y.min(ny - 1) + ny * z.min(nz - 1))) as usize)
    };
    let mut out = Vec::with_capacity((px * py * pz) as usize);
    for z in 0..pz {
        for y in 0..py {
            for x in 0..px {
                let mut v = [0u32; 8];
                for (i, s) in v.iter_mut().enumerate() {
                    let (dx, dy, dz) = ((i & 1) as u32, (i >> 1 & 1) as u32, (i >> 2) as u32);
                    *s = at(2 * x + dx, 2 * y + dy, 2 * z + dz);
                }
                out.push(mode_of(&mut v));
            }
        }
    }
    let d = volume.desc();
    let data = match d.dtype {
        DType::U8 => VolumeData::U8(out.iter().map(|&v| v as u8).collect()),
        DType::U16 => VolumeData::U16(out.iter().map(|&v| v as u16).collect()),
        _ => VolumeData::U32(out),
    };
    let desc = VolumeDesc {
        dims: [px, py, pz],
        dtype: data.dtype(),
        spacing: [0, 1, 2].map(|a| d.spacing[a] * 2.0),
        value_range: d.value_range,
        kind: d.kind,
    };
    Volume::new(desc, data).expect("a halved valid volume is valid")
}

/// The share of the voxels of `fine` whose label differs from the coarse
/// voxel that stands for them (`coarse` = `fine` halved `levels` times along
/// every axis): the error of drawing a label region from a coarser level.
pub fn changed_share(fine: &Volume, coarse: &Volume, levels: u32) -> f64 {
    let [nx, ny, nz] = fine.dims();
    let [cx, cy, _] = coarse.dims();
    let (f, c) = (fine.data(), coarse.data());
    let mut changed = 0u64;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let i = (x + nx * (y + ny * z)) as usize;
                let j = ((x >> levels) + cx * ((y >> levels) + cy * (z >> levels))) as usize;
                changed += (f.label(i) != c.label(j)) as u64;
            }
        }
    }
    changed as f64 / fine.desc().voxel_count() as f64
}

/// How one label is drawn.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LabelStyle {
    /// Linear RGB, 0..1.
    pub color: [f32; 3],
    /// Opacity per reference step (as a transfer function's alpha), 0..1.
    pub opacity: f32,
    /// Drawn at all.
    pub visible: bool,
}

/// A colour for label `id` that tells neighbouring ids apart: the hue from a
/// hash of the id (golden-ratio spaced), high saturation and value.
pub fn hashed_color(id: u32) -> [f32; 3] {
    // splitmix32-style mixing, then a golden-ratio hue walk.
    let mut h = id.wrapping_add(0x9e37_79b9);
    h = (h ^ (h >> 16)).wrapping_mul(0x85eb_ca6b);
    h = (h ^ (h >> 13)).wrapping_mul(0xc2b2_ae35);
    h ^= h >> 16;
    let hue = ((id as f64 * 0.618_033_988_749_895) + (h & 0xff) as f64 / 2048.0).fract();
    let sat = 0.55 + 0.35 * ((h >> 8) & 0xff) as f64 / 255.0;
    let val = 0.75 + 0.25 * ((h >> 16) & 0xff) as f64 / 255.0;
    hsv_to_rgb(hue, sat, val)
}

fn hsv_to_rgb(h: f64, s: f64, v: f64) -> [f32; 3] {
    let i = (h * 6.0).floor();
    let f = h * 6.0 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - f * s), v * (1.0 - (1.0 - f) * s));
    let (r, g, b) = match i as i64 % 6 {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    };
    [r as f32, g as f32, b as f32]
}

/// How a label map is drawn: per label colour, opacity and visibility (ids
/// without an explicit style get [`hashed_color`] and the default opacity;
/// the background id is hidden), a selected set drawn at its own opacity
/// with the rest dimmed, and a hovered label highlighted. Editable at run
/// time: the renderer takes [`to_transfer_function`](Self::to_transfer_function)
/// as it takes a transfer function; the store is never touched.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LabelTable {
    /// Explicit styles by id.
    #[serde(default)]
    pub styles: BTreeMap<u32, LabelStyle>,
    /// Opacity of labels without an explicit style.
    #[serde(default = "default_opacity")]
    pub default_opacity: f32,
    /// Whether labels without an explicit style are drawn (false after
    /// [`show_only`](Self::show_only): every other id is hidden, also ids
    /// absent from the data, so empty-space skipping by id ranges skips what
    /// holds hidden labels only).
    #[serde(default = "default_visible")]
    pub default_visible: bool,
    /// The id drawn as nothing unless styled (`None`: every id is drawn).
    #[serde(default = "default_background")]
    pub background: Option<u32>,
    /// The selected labels (empty: no selection).
    #[serde(default)]
    pub selected: BTreeSet<u32>,
    /// Opacity of selected labels while a selection exists (Neuroglancer: 0.5).
    #[serde(default = "default_selected_opacity")]
    pub selected_opacity: f32,
    /// Opacity of the labels outside a non-empty selection (Neuroglancer: 0).
    #[serde(default)]
    pub unselected_opacity: f32,
    /// The label under the pointer, drawn brighter and at least half opaque.
    #[serde(default)]
    pub hover: Option<u32>,
}

fn default_opacity() -> f32 {
    0.5
}
fn default_visible() -> bool {
    true
}
fn default_background() -> Option<u32> {
    Some(0)
}
fn default_selected_opacity() -> f32 {
    0.5
}

impl Default for LabelTable {
    fn default() -> Self {
        LabelTable {
            styles: BTreeMap::new(),
            default_opacity: default_opacity(),
            default_visible: true,
            background: default_background(),
            selected: BTreeSet::new(),
            selected_opacity: default_selected_opacity(),
            unselected_opacity: 0.0,
            hover: None,
        }
    }
}

impl LabelTable {
    /// The style of `id` before selection and hover.
    pub fn style(&self, id: u32) -> LabelStyle {
        if let Some(s) = self.styles.get(&id) {
            return *s;
        }
        LabelStyle {
            color: hashed_color(id),
            opacity: self.default_opacity,
            visible: self.default_visible && self.background != Some(id),
        }
    }

    /// The colour and opacity `id` is drawn with (straight RGB, alpha):
    /// hidden labels are transparent; with a selection, selected labels
    /// take `selected_opacity` and the others `unselected_opacity`; the
    /// hovered label is lightened and at least half opaque.
    pub fn rgba(&self, id: u32) -> [f32; 4] {
        let s = self.style(id);
        if !s.visible {
            return [s.color[0], s.color[1], s.color[2], 0.0];
        }
        let mut a = s.opacity;
        if !self.selected.is_empty() {
            a = if self.selected.contains(&id) {
                self.selected_opacity
            } else {
                self.unselected_opacity
            };
        }
        let mut c = s.color;
        if self.hover == Some(id) {
            c = c.map(|x| 0.5 * x + 0.5);
            a = a.max(0.5);
        }
        [c[0], c[1], c[2], a.clamp(0.0, 1.0)]
    }

    /// Sets the colour of `id`.
    pub fn set_color(&mut self, id: u32, color: [f32; 3]) {
        let mut s = self.style(id);
        s.color = color;
        self.styles.insert(id, s);
    }

    /// Sets the opacity of `id`.
    pub fn set_opacity(&mut self, id: u32, opacity: f32) {
        let mut s = self.style(id);
        s.opacity = opacity;
        self.styles.insert(id, s);
    }

    /// Shows or hides `id`.
    pub fn set_visible(&mut self, id: u32, visible: bool) {
        let mut s = self.style(id);
        s.visible = visible;
        self.styles.insert(id, s);
    }

    /// Shows the labels of `keep` and hides every other id (styled or not).
    pub fn show_only(&mut self, keep: &[u32]) {
        self.default_visible = false;
        for s in self.styles.values_mut() {
            s.visible = false;
        }
        for &id in keep {
            self.set_visible(id, true);
        }
    }

    /// Shows every label (but an unstyled background).
    pub fn show_all(&mut self) {
        self.default_visible = true;
        for s in self.styles.values_mut() {
            s.visible = true;
        }
    }

    /// The exact per-label transfer function of a label volume: entry `i`
    /// is label `i`'s [`rgba`](Self::rgba) ([`LABEL_TABLE_ENTRIES`] entries).
    pub fn to_transfer_function(&self) -> TransferFunction {
        let entries = (0..LABEL_TABLE_ENTRIES as u32)
            .map(|i| self.rgba(i))
            .collect();
        TransferFunction::from_entries(entries)
    }

    /// Reads a colour table: mricron's `.lut` (768 bytes: 256 red values,
    /// then 256 green, then 256 blue; label `i` takes entry `i`), or this
    /// type's JSON form. Entry 0 stays the hidden background.
    pub fn from_file_bytes(bytes: &[u8]) -> Result<LabelTable, LabelError> {
        if bytes.len() == 768 {
            return Ok(Self::from_mricron_lut(bytes));
        }
        let text = std::str::from_utf8(bytes)
            .map_err(|_| LabelError::Table("neither a 768-byte .lut nor UTF-8 JSON".into()))?;
        serde_json::from_str(text).map_err(|e| LabelError::Table(e.to_string()))
    }

    /// A table from mricron's 768-byte `.lut` (see [`from_file_bytes`](Self::from_file_bytes)).
    pub fn from_mricron_lut(bytes: &[u8]) -> LabelTable {
        let mut t = LabelTable::default();
        for i in 1..256u32 {
            let c = [0, 256, 512]
                .map(|o| bytes.get(o + i as usize).copied().unwrap_or(0) as f32 / 255.0);
            t.set_color(i, c);
        }
        t
    }

    /// The JSON form (every field; read back by [`from_file_bytes`](Self::from_file_bytes)).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a label table serialises")
    }
}

#[cfg(test)]
mod tests;
