//! Window and level: the intensity mapping of MIP and slice views, separate
//! from the DVR transfer function (docs/rendering-model.md, "Window and
//! level").
//!
//! A [`Window`] is given in the volume's raw values (Hounsfield units for a
//! CT): centre and width, or min and max. Through the volume's value range it
//! becomes an interval of normalized values; a value maps to
//! `x = clamp((v - lo) / (hi - lo), 0, 1)` and `x` to a colour through a
//! [`ColorMap`]. [`Window::auto`] picks the 0.5 and 99.5 percentiles of a
//! histogram.

use thiserror::Error;

/// A window that cannot map values.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[non_exhaustive]
pub enum WindowError {
    /// The centre, width, min or max is NaN or infinite.
    #[error("the window's {field} is not finite")]
    NotFinite {
        /// The field.
        field: &'static str,
    },
    /// The width is not positive (min not below max).
    #[error("the window's width {width} is not > 0")]
    BadWidth {
        /// The width.
        width: f64,
    },
    /// The value range is not finite or empty.
    #[error("value range {0:?} is not finite with lo < hi")]
    BadRange([f64; 2]),
    /// The histogram has no bins or no counts.
    #[error("the histogram is empty")]
    EmptyHistogram,
}

/// An intensity window in the volume's raw values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    centre: f64,
    width: f64,
}

impl Window {
    /// A window of `width` raw units about `centre` (the level).
    pub fn new(centre: f64, width: f64) -> Result<Window, WindowError> {
        if !centre.is_finite() {
            return Err(WindowError::NotFinite { field: "centre" });
        }
        if !width.is_finite() {
            return Err(WindowError::NotFinite { field: "width" });
        }
        if width <= 0.0 {
            return Err(WindowError::BadWidth { width });
        }
        Ok(Window { centre, width })
    }

    /// The window from `min` to `max`.
    pub fn from_min_max(min: f64, max: f64) -> Result<Window, WindowError> {
        if !min.is_finite() {
            return Err(WindowError::NotFinite { field: "min" });
        }
        if !max.is_finite() {
            return Err(WindowError::NotFinite { field: "max" });
        }
        Window::new(0.5 * (min + max), max - min)
    }

    /// The window over a whole value range.
    pub fn full(range: [f32; 2]) -> Result<Window, WindowError> {
        Window::from_min_max(range[0] as f64, range[1] as f64)
    }

    /// The centre (level).
    pub fn centre(&self) -> f64 {
        self.centre
    }

    /// The width.
    pub fn width(&self) -> f64 {
        self.width
    }

    /// The lower end.
    pub fn min(&self) -> f64 {
        self.centre - 0.5 * self.width
    }

    /// The upper end.
    pub fn max(&self) -> f64 {
        self.centre + 0.5 * self.width
    }

    /// The window in normalized values of a volume whose raw values span
    /// `range` (`VolumeDesc::value_range`).
    pub fn normalized(&self, range: [f32; 2]) -> Result<[f64; 2], WindowError> {
        let [lo, hi] = range.map(f64::from);
        if !(lo.is_finite() && hi.is_finite() && hi > lo) {
            return Err(WindowError::BadRange([lo, hi]));
        }
        let n = |v: f64| (v - lo) / (hi - lo);
        Ok([n(self.min()), n(self.max())])
    }

    /// The position `x` in 0..1 of a raw value in the window.
    pub fn position(&self, raw: f64) -> f64 {
        ((raw - self.min()) / self.width).clamp(0.0, 1.0)
    }

    /// The window from the 0.5 and 99.5 percentiles of a histogram of `bins`
    /// equal bins over the raw range `range` (the percentile interpolated
    /// linearly inside its bin). A histogram whose mass lies in one bin gets
    /// that bin's extent.
    pub fn auto(bins: &[u64], range: [f64; 2]) -> Result<Window, WindowError> {
        Window::from_percentiles(bins, range, 0.005, 0.995)
    }

    /// [`Self::auto`] over a histogram of a volume's raw values (`bins` equal
    /// bins over its value range; values outside it count in the end bins).
    pub fn auto_of(volume: &crate::Volume, bins: usize) -> Result<Window, WindowError> {
        let range = volume.desc().value_range.map(f64::from);
        Window::auto(&histogram(volume, bins, range)?, range)
    }

    /// The window between the `lo` and `hi` quantiles (0..1) of a histogram
    /// (see [`Self::auto`]).
    pub fn from_percentiles(
        bins: &[u64],
        range: [f64; 2],
        lo: f64,
        hi: f64,
    ) -> Result<Window, WindowError> {
        let [a, b] = range;
        if !(a.is_finite() && b.is_finite() && b > a) {
            return Err(WindowError::BadRange(range));
        }
        let total: u64 = bins.iter().sum();
        if bins.is_empty() || total == 0 {
            return Err(WindowError::EmptyHistogram);
        }
        let bin_width = (b - a) / bins.len() as f64;
        let quantile = |q: f64| -> f64 {
            let target = q.clamp(0.0, 1.0) * total as f64;
            let mut below = 0u64;
            for (i, &c) in bins.iter().enumerate() {
                if c > 0 && (below + c) as f64 >= target {
                    let f = ((target - below as f64) / c as f64).clamp(0.0, 1.0);
                    return a + (i as f64 + f) * bin_width;
                }
                below += c;
            }
            b
        };
        let (mut min, mut max) = (quantile(lo), quantile(hi));
        if max <= min {
            // All the mass at one point: that point's bin.
            let i = ((min - a) / bin_width)
                .floor()
                .clamp(0.0, bins.len() as f64 - 1.0);
            min = a + i * bin_width;
            max = min + bin_width;
        }
        Window::from_min_max(min, max)
    }
}

/// A histogram of `bins` equal bins over the raw range `range` of a volume's
/// values (values outside the range count in the end bins, NaN in none).
pub fn histogram(
    volume: &crate::Volume,
    bins: usize,
    range: [f64; 2],
) -> Result<Vec<u64>, WindowError> {
    let [a, b] = range;
    if !(a.is_finite() && b.is_finite() && b > a) {
        return Err(WindowError::BadRange(range));
    }
    if bins == 0 {
        return Err(WindowError::EmptyHistogram);
    }
    let mut out = vec![0u64; bins];
    let scale = bins as f64 / (b - a);
    let data = volume.data();
    for i in 0..data.len() {
        let v = data.get(i) as f64;
        if v.is_nan() {
            continue;
        }
        let k = ((v - a) * scale).floor().clamp(0.0, (bins - 1) as f64) as usize;
        out[k] += 1;
    }
    Ok(out)
}

/// Standard CT windows in Hounsfield units (centre, width).
///
/// Brain 40/80, bone 400/1800, lung -600/1500 and abdomen (soft tissue)
/// 40/400, as tabulated by Radiopaedia's "Windowing (CT)" article; bone is
/// also commonly read at 300/1500.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CtPreset {
    /// 40 / 80.
    Brain,
    /// 400 / 1800.
    Bone,
    /// -600 / 1500.
    Lung,
    /// 40 / 400.
    Abdomen,
}

impl CtPreset {
    /// Every preset.
    pub const ALL: [CtPreset; 4] = [
        CtPreset::Brain,
        CtPreset::Bone,
        CtPreset::Lung,
        CtPreset::Abdomen,
    ];

    /// (centre, width) in Hounsfield units.
    pub fn centre_width(self) -> (f64, f64) {
        match self {
            CtPreset::Brain => (40.0, 80.0),
            CtPreset::Bone => (400.0, 1800.0),
            CtPreset::Lung => (-600.0, 1500.0),
            CtPreset::Abdomen => (40.0, 400.0),
        }
    }

    /// The window (raw values are Hounsfield units).
    pub fn window(self) -> Window {
        let (c, w) = self.centre_width();
        Window {
            centre: c,
            width: w,
        }
    }
}

/// Colour maps of MIP and slice views.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ColorMap {
    /// Black to white.
    #[default]
    Grey,
    /// Black, red, yellow, white (`r = 3x`, `g = 3x - 1`, `b = 3x - 2`,
    /// clamped).
    Hot,
    /// Matplotlib's viridis, from its table's entries 0, 32, ..., 224 and
    /// 255, interpolated linearly.
    Viridis,
}

/// Viridis at x = 0, 1/8, ..., 1 (matplotlib's `_viridis_data` entries 0,
/// 32, 64, 96, 128, 160, 192, 224 and 255).
pub const VIRIDIS: [[f32; 3]; 9] = [
    [0.267004, 0.004874, 0.329415],
    [0.282623, 0.140926, 0.457517],
    [0.253935, 0.265254, 0.529983],
    [0.206756, 0.371758, 0.553117],
    [0.163625, 0.471133, 0.558148],
    [0.127568, 0.566949, 0.550556],
    [0.134692, 0.658636, 0.517649],
    [0.266941, 0.748751, 0.440573],
    [0.993248, 0.906157, 0.143936],
];

impl ColorMap {
    /// Its id in the kernels (`MAP_*` in common.wgsl).
    pub fn id(self) -> u32 {
        match self {
            ColorMap::Grey => 1,
            ColorMap::Hot => 2,
            ColorMap::Viridis => 3,
        }
    }

    /// The colour of window position `x` (clamped to 0..1).
    pub fn color(self, x: f64) -> [f64; 3] {
        let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
        match self {
            ColorMap::Grey => [x; 3],
            ColorMap::Hot => [0.0, 1.0, 2.0].map(|k| (3.0 * x - k).clamp(0.0, 1.0)),
            ColorMap::Viridis => {
                let n = (VIRIDIS.len() - 1) as f64;
                let p = x * n;
                let i = (p.floor() as usize).min(VIRIDIS.len() - 2);
                let f = p - i as f64;
                std::array::from_fn(|c| {
                    let (a, b) = (VIRIDIS[i][c] as f64, VIRIDIS[i + 1][c] as f64);
                    a + (b - a) * f
                })
            }
        }
    }
}

/// The intensity mapping of MIP and slice views: a window and a colour map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intensity {
    /// The window (raw values).
    pub window: Window,
    /// The colour map.
    pub color_map: ColorMap,
}

impl Intensity {
    /// `window` through `color_map`.
    pub fn new(window: Window, color_map: ColorMap) -> Intensity {
        Intensity { window, color_map }
    }

    /// Grey over the whole value range `range`.
    pub fn grey(range: [f32; 2]) -> Result<Intensity, WindowError> {
        Ok(Intensity::new(Window::full(range)?, ColorMap::Grey))
    }

    /// The opaque colour of normalized value `v` of a volume whose raw values
    /// span `range` (as the kernels compute it, in f64).
    pub fn map(&self, v: f64, range: [f32; 2]) -> Result<[f64; 3], WindowError> {
        let [lo, hi] = self.window.normalized(range)?;
        Ok(self.color_map.color((v - lo) / (hi - lo)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn forms_agree_and_bad_windows_are_typed_errors() {
        let a = Window::new(40.0, 80.0).unwrap();
        let b = Window::from_min_max(0.0, 80.0).unwrap();
        assert_eq!(a, b);
        assert_eq!((a.min(), a.max()), (0.0, 80.0));
        assert_eq!(a.position(20.0), 0.25);
        assert_eq!(a.position(-5.0), 0.0);
        assert_eq!(a.position(500.0), 1.0);
        assert!(matches!(
            Window::new(0.0, 0.0),
            Err(WindowError::BadWidth { .. })
        ));
        assert!(Window::new(f64::NAN, 1.0).is_err());
        assert!(Window::new(0.0, f64::INFINITY).is_err());
        assert!(Window::from_min_max(5.0, 1.0).is_err());
        assert!(a.normalized([1.0, 1.0]).is_err());
        assert!(a.normalized([f32::NAN, 1.0]).is_err());
        assert_eq!(
            Window::auto(&[], [0.0, 1.0]),
            Err(WindowError::EmptyHistogram)
        );
        assert_eq!(
            Window::auto(&[0, 0], [0.0, 1.0]),
            Err(WindowError::EmptyHistogram)
        );
        assert!(Window::auto(&[1], [1.0, 1.0]).is_err());
    }

    #[test]
    fn ct_presets_map_through_the_value_range() {
        // A CT stored as raw HU over [-1024, 3071].
        let range = [-1024.0, 3071.0];
        let w = CtPreset::Brain.window().normalized(range).unwrap();
        assert!((w[0] - 1024.0 / 4095.0).abs() < 1e-12);
        assert!((w[1] - 1104.0 / 4095.0).abs() < 1e-12);
        for p in CtPreset::ALL {
            let (c, wd) = p.centre_width();
            assert_eq!(p.window(), Window::new(c, wd).unwrap());
        }
        let i = Intensity::new(CtPreset::Brain.window(), ColorMap::Grey);
        let v = (40.0 + 1024.0) / 4095.0;
        let c = i.map(v, range).unwrap();
        assert!((c[0] - 0.5).abs() < 1e-9);
    }

    #[test]
    fn colour_maps_span_their_ends() {
        assert_eq!(ColorMap::Grey.color(0.25), [0.25; 3]);
        assert_eq!(ColorMap::Hot.color(0.0), [0.0; 3]);
        assert_eq!(ColorMap::Hot.color(0.5), [1.0, 0.5, 0.0]);
        assert_eq!(ColorMap::Hot.color(1.0), [1.0; 3]);
        let v0 = ColorMap::Viridis.color(0.0);
        let v1 = ColorMap::Viridis.color(1.0);
        for c in 0..3 {
            assert!((v0[c] - VIRIDIS[0][c] as f64).abs() < 1e-7);
            assert!((v1[c] - VIRIDIS[8][c] as f64).abs() < 1e-7);
        }
        assert_eq!(ColorMap::Grey.color(f64::NAN), [0.0; 3]);
    }

    #[test]
    fn auto_window_of_a_uniform_histogram() {
        // 1000 equal bins over 0..1000: the percentiles are 5 and 995.
        let bins = vec![7u64; 1000];
        let w = Window::auto(&bins, [0.0, 1000.0]).unwrap();
        assert!((w.min() - 5.0).abs() < 1e-9, "{w:?}");
        assert!((w.max() - 995.0).abs() < 1e-9, "{w:?}");
        // All the mass in one bin: that bin.
        let mut one = vec![0u64; 10];
        one[3] = 50;
        let w = Window::auto(&one, [0.0, 10.0]).unwrap();
        assert!(w.min() >= 3.0 && w.max() <= 4.0 && w.width() > 0.0, "{w:?}");
    }

    #[test]
    fn auto_window_of_a_volume() {
        // Values 0..=999, one each (a ramp): the window spans 5..995.
        let v = crate::Volume::new(
            crate::VolumeDesc {
                dims: [10, 10, 10],
                dtype: crate::DType::F32,
                spacing: [1.0; 3],
                value_range: [0.0, 1000.0],
                kind: Default::default(),
            },
            crate::VolumeData::F32((0..1000).map(|i| i as f32).collect()),
        )
        .unwrap();
        let w = Window::auto_of(&v, 1000).unwrap();
        assert!(
            (w.min() - 5.0).abs() < 1e-9 && (w.max() - 995.0).abs() < 1e-9,
            "{w:?}"
        );
        assert_eq!(
            histogram(&v, 0, [0.0, 1.0]),
            Err(WindowError::EmptyHistogram)
        );
        assert!(histogram(&v, 4, [1.0, 0.0]).is_err());
        let h = histogram(&v, 4, [0.0, 500.0]).unwrap();
        assert_eq!(h, vec![125, 125, 125, 625]);
    }

    proptest! {
        /// The auto window lies in the range, has a positive width, holds at
        /// least 99% of the mass (up to the bins its ends fall in) and at most
        /// 0.5% of the mass lies wholly below it (and above it).
        #[test]
        fn auto_window_holds_the_central_mass(
            bins in proptest::collection::vec(0u64..1000, 1..64),
            lo in -5000.0f64..5000.0,
            span in 1e-3f64..1e4,
        ) {
            let total: u64 = bins.iter().sum();
            prop_assume!(total > 0);
            let range = [lo, lo + span];
            let w = Window::auto(&bins, range).unwrap();
            let bw = span / bins.len() as f64;
            let eps = 1e-9 * span.max(lo.abs());
            prop_assert!(w.width() > 0.0);
            prop_assert!(w.min() >= lo - eps && w.max() <= lo + span + eps);
            // Mass in bins wholly below the window and wholly above it.
            let below: u64 = bins.iter().enumerate()
                .filter(|(i, _)| lo + (*i as f64 + 1.0) * bw <= w.min() - eps)
                .map(|(_, c)| *c).sum();
            let above: u64 = bins.iter().enumerate()
                .filter(|(i, _)| lo + *i as f64 * bw >= w.max() + eps)
                .map(|(_, c)| *c).sum();
            prop_assert!(below as f64 <= 0.005 * total as f64 + 1e-9, "{below} of {total}");
            prop_assert!(above as f64 <= 0.005 * total as f64 + 1e-9, "{above} of {total}");
        }

        /// Centre/width and min/max describe the same window.
        #[test]
        fn forms_round_trip(c in -1e4f64..1e4, w in 1e-3f64..1e4) {
            let a = Window::new(c, w).unwrap();
            let b = Window::from_min_max(a.min(), a.max()).unwrap();
            prop_assert!((a.centre() - b.centre()).abs() < 1e-9 * (1.0 + c.abs() + w));
            prop_assert!((a.width() - b.width()).abs() < 1e-9 * (1.0 + c.abs() + w));
        }
    }
}
