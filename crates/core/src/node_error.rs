//! The per-node error record the store keeps ([`NodeError`], store format
//! version 2; what it bounds: `crate::lod`'s module documentation) and how
//! the builder fills it ([`BinStats`], [`bin_of`]).

/// Bins of a node's value range in [`NodeError`].
pub const ERROR_BINS: usize = 16;

/// Largest quantised deviation ([`NodeError::dev`]): `max - min`.
pub const DEV_SCALE: u16 = u16::MAX;

/// A node's recorded error bound and expected error (see the module
/// documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct NodeError {
    /// Bit `b` set: some coarse voxel of the node falls in bin `b`.
    pub occupied: u16,
    /// Bin `b`'s largest deviation from the finest level (the bound), in units
    /// of `(max - min) / 65535`, rounded up (so decoding never underestimates).
    pub dev: [u16; ERROR_BINS],
    /// Bin `b`'s typical deviation: the root mean square over its coarse
    /// voxels `C` of the RMS of `F - C` over the finest voxels `F` of `C`'s own
    /// footprint; same unit, rounded up.
    pub rms: [u16; ERROR_BINS],
    /// Bin `b`'s share of the node's coarse voxels, in units of 1/65535, rounded.
    pub weight: [u16; ERROR_BINS],
}

/// What the builder measured in one bin of a node.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BinStats {
    /// Coarse voxels in the bin.
    pub count: u64,
    /// Their largest deviation from the finest voxels of their 3x3x3
    /// neighbourhood of footprints (raw units).
    pub dev: f64,
    /// Sum over them of the mean square of `F - C` over their own footprint.
    pub sum_sq: f64,
}

/// The bin of raw value `v` in a node of range `[min, max]` (values outside
/// clamp to the first or last bin; a zero-width range has only bin 0).
pub fn bin_of(v: f64, min: f64, max: f64) -> usize {
    let span = max - min;
    if span.is_nan() || span <= 0.0 {
        return 0;
    }
    let b = ((v - min) / span * ERROR_BINS as f64).floor();
    if b.is_nan() {
        0
    } else {
        b.clamp(0.0, (ERROR_BINS - 1) as f64) as usize
    }
}

impl NodeError {
    /// Encodes what the builder measured per bin of a node of range
    /// `[min, max]`, rounding deviations up. Deviations are clamped to
    /// `0..=max - min` (no fine and coarse value of a subtree lie further apart).
    pub fn encode(bins: &[BinStats; ERROR_BINS], min: f64, max: f64) -> NodeError {
        let span = max - min;
        let total: u64 = bins.iter().map(|b| b.count).sum();
        let q = |d: f64| -> u16 {
            if span > 0.0 && d.is_finite() {
                (d.max(0.0) / span * DEV_SCALE as f64)
                    .ceil()
                    .clamp(0.0, DEV_SCALE as f64) as u16
            } else if span > 0.0 {
                DEV_SCALE
            } else {
                0
            }
        };
        let mut e = NodeError::default();
        for (b, st) in bins.iter().enumerate() {
            if st.count == 0 {
                continue;
            }
            e.occupied |= 1 << b;
            e.dev[b] = q(st.dev);
            e.rms[b] = q((st.sum_sq / st.count as f64).sqrt()).min(e.dev[b]);
            e.weight[b] = ((st.count as f64 / total as f64) * DEV_SCALE as f64).round() as u16;
        }
        e
    }

    /// A label store's record (`crate::labels`): the share of the node's
    /// finest voxels whose label differs from the node's voxel covering them
    /// (0..=1), rounded up to 1/65535 in bin 0's deviation and typical
    /// deviation (bin 0 occupied when the share is not zero). Label ids have
    /// no value bins: a label either changes or does not.
    pub fn from_label_share(share: f64) -> NodeError {
        let q = if share.is_nan() {
            DEV_SCALE
        } else {
            (share.clamp(0.0, 1.0) * DEV_SCALE as f64).ceil() as u16
        };
        let mut e = NodeError::default();
        if q > 0 {
            e.occupied = 1;
            e.dev[0] = q;
            e.rms[0] = q;
            e.weight[0] = DEV_SCALE;
        }
        e
    }

    /// The share a label store's record holds ([`Self::from_label_share`]).
    pub fn label_share(&self) -> f64 {
        self.dev[0] as f64 / DEV_SCALE as f64
    }

    /// Whether bin `b` is occupied.
    pub fn is_occupied(&self, b: usize) -> bool {
        b < ERROR_BINS && self.occupied & (1 << b) != 0
    }

    /// Bin `b`'s deviation bound in raw units, for a node of range `[min, max]`.
    pub fn deviation(&self, b: usize, min: f64, max: f64) -> f64 {
        let span = (max - min).max(0.0);
        self.dev
            .get(b)
            .map_or(0.0, |&q| q as f64 / DEV_SCALE as f64 * span)
    }

    /// Bin `b`'s typical (RMS) deviation in raw units.
    pub fn typical_deviation(&self, b: usize, min: f64, max: f64) -> f64 {
        let span = (max - min).max(0.0);
        self.rms
            .get(b)
            .map_or(0.0, |&q| q as f64 / DEV_SCALE as f64 * span)
    }

    /// Bin `b`'s share of the node's coarse voxels (0..=1).
    pub fn share(&self, b: usize) -> f64 {
        self.weight
            .get(b)
            .map_or(0.0, |&w| w as f64 / DEV_SCALE as f64)
    }

    /// The widened bin `W_b = [bin_lo - dev_b, bin_hi + dev_b]` (raw units).
    pub fn widened(&self, b: usize, min: f64, max: f64) -> (f64, f64) {
        self.widened_by(b, min, max, self.deviation(b, min, max))
    }

    /// Bin `b` widened by `d` on each side (raw units).
    pub fn widened_by(&self, b: usize, min: f64, max: f64, d: f64) -> (f64, f64) {
        let w = (max - min).max(0.0) / ERROR_BINS as f64;
        let (lo, hi) = (min + b as f64 * w, min + (b + 1) as f64 * w);
        (lo - d, hi + d)
    }

    /// The largest deviation over the occupied bins (raw units).
    pub fn max_deviation(&self, min: f64, max: f64) -> f64 {
        (0..ERROR_BINS)
            .filter(|&b| self.is_occupied(b))
            .map(|b| self.deviation(b, min, max))
            .fold(0.0, f64::max)
    }
}
