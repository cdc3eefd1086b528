//! A transfer function as an editor holds it: colour and opacity control
//! points, their interpolation into a [`TransferFunction`], hit testing and
//! editing, presets, and JSON files. GPU-free: a host's own editor (the
//! viewer's egui widget is one) maps it to the screen.
//!
//! Positions are normalized values (0..1 over the volume's value range);
//! colours and opacities are piecewise linear between their points and held
//! constant beyond the first and last point. The two lists are independent, as
//! in ParaView: moving an opacity point never changes a colour.

use super::{TfError, TransferFunction};
use serde::{Deserialize, Serialize};

/// Entries of the table a model is sampled into by default.
pub const TABLE_ENTRIES: usize = 1024;

/// A colour control point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ColorPoint {
    /// Normalized value.
    pub x: f32,
    /// Linear RGB, 0..1.
    pub rgb: [f32; 3],
}

/// An opacity control point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OpacityPoint {
    /// Normalized value.
    pub x: f32,
    /// Opacity per reference length (one voxel), 0..1.
    pub a: f32,
}

/// A transfer function as the editor holds it. Both lists are sorted by `x`
/// and never empty.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TfModel {
    /// Colour points.
    pub colors: Vec<ColorPoint>,
    /// Opacity points.
    pub opacity: Vec<OpacityPoint>,
}

/// A transfer-function file or edit that cannot be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TfFileError {
    /// Reading or writing the file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file is not a transfer function in the editor's JSON form.
    #[error("{path}: not a transfer function: {source}")]
    Json {
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        source: serde_json::Error,
    },
    /// A list is empty or a value is not finite or outside 0..1.
    #[error("bad transfer function: {0}")]
    Invalid(String),
    /// The table could not be built.
    #[error(transparent)]
    Table(#[from] TfError),
}

/// Named starting points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TfPreset {
    /// CT in Hounsfield units: faint soft tissue, opaque bone.
    CtBone,
    /// CT: skin and soft tissue, faint bone.
    CtSoft,
    /// MRI (T1): brain tissue in warm tones over transparent background.
    Mri,
    /// Fluorescence microscopy: dim background hidden, bright structures green.
    Microscopy,
    /// A grey ramp over the whole range.
    Grey,
    /// An opaque ivory surface where values rise above about 0.1 (solids
    /// with a soft edge, such as the procedural Mandelbulb); shading draws
    /// the shape.
    Surface,
}

impl TfPreset {
    /// All, in menu order.
    pub const ALL: [TfPreset; 6] = [
        TfPreset::CtBone,
        TfPreset::CtSoft,
        TfPreset::Mri,
        TfPreset::Microscopy,
        TfPreset::Grey,
        TfPreset::Surface,
    ];

    /// Its name (also its script name).
    pub fn name(self) -> &'static str {
        match self {
            TfPreset::CtBone => "ct-bone",
            TfPreset::CtSoft => "ct-soft",
            TfPreset::Mri => "mri",
            TfPreset::Microscopy => "microscopy",
            TfPreset::Grey => "grey",
            TfPreset::Surface => "surface",
        }
    }

    /// Parses a name.
    pub fn parse(s: &str) -> Option<TfPreset> {
        TfPreset::ALL.into_iter().find(|p| p.name() == s)
    }
}

/// Linear interpolation of `f(x)` over points sorted by position, held
/// constant outside them.
fn interpolate<const N: usize>(points: &[(f32, [f32; N])], x: f32) -> [f32; N] {
    let Some(first) = points.first() else {
        return [0.0; N];
    };
    match points.iter().position(|p| p.0 > x) {
        Some(0) => first.1,
        None => points[points.len() - 1].1,
        Some(j) => {
            let (x0, c0) = points[j - 1];
            let (x1, c1) = points[j];
            let f = if x1 > x0 { (x - x0) / (x1 - x0) } else { 1.0 };
            std::array::from_fn(|k| c0[k] + (c1[k] - c0[k]) * f)
        }
    }
}

impl TfModel {
    /// A preset. CT presets are in Hounsfield units, mapped through the
    /// volume's raw value range `range`; the others are in normalized values.
    pub fn preset(p: TfPreset, range: [f32; 2]) -> TfModel {
        let span = (range[1] - range[0]).max(f32::MIN_POSITIVE);
        let hu = |v: f32| ((v - range[0]) / span).clamp(0.0, 1.0);
        let c = |x: f32, rgb: [f32; 3]| ColorPoint { x, rgb };
        let o = |x: f32, a: f32| OpacityPoint { x, a };
        let mut m = match p {
            TfPreset::CtBone => TfModel {
                colors: vec![
                    c(hu(-200.0), [0.75, 0.4, 0.3]),
                    c(hu(250.0), [0.9, 0.85, 0.75]),
                    c(hu(600.0), [1.0, 0.95, 0.85]),
                ],
                opacity: vec![o(hu(250.0), 0.0), o(hu(600.0), 1.0)],
            },
            TfPreset::CtSoft => TfModel {
                colors: vec![
                    c(hu(-500.0), [0.6, 0.3, 0.2]),
                    c(hu(-100.0), [0.8, 0.5, 0.4]),
                    c(hu(150.0), [0.9, 0.6, 0.5]),
                    c(hu(300.0), [1.0, 1.0, 0.9]),
                    c(hu(500.0), [1.0, 1.0, 0.95]),
                ],
                opacity: vec![
                    o(hu(-500.0), 0.0),
                    o(hu(-100.0), 0.02),
                    o(hu(150.0), 0.03),
                    o(hu(300.0), 0.0),
                    o(hu(500.0), 0.3),
                ],
            },
            TfPreset::Mri => TfModel {
                colors: vec![
                    c(0.1, [0.3, 0.1, 0.05]),
                    c(0.35, [0.9, 0.5, 0.3]),
                    c(0.7, [1.0, 0.9, 0.8]),
                ],
                opacity: vec![o(0.12, 0.0), o(0.35, 0.08), o(0.7, 0.4)],
            },
            TfPreset::Microscopy => TfModel {
                colors: vec![c(0.0, [0.0, 0.2, 0.05]), c(1.0, [0.6, 1.0, 0.5])],
                opacity: vec![o(0.15, 0.0), o(0.5, 0.2), o(1.0, 0.8)],
            },
            TfPreset::Grey => TfModel {
                colors: vec![c(0.0, [0.0; 3]), c(1.0, [1.0; 3])],
                opacity: vec![o(0.0, 0.0), o(1.0, 0.5)],
            },
            TfPreset::Surface => TfModel {
                colors: vec![c(0.08, [0.85, 0.7, 0.55]), c(0.3, [0.95, 0.88, 0.75])],
                opacity: vec![o(0.08, 0.0), o(0.3, 0.9), o(1.0, 1.0)],
            },
        };
        m.sort();
        m
    }

    /// Sorts both lists by position (stable: equal positions keep their order).
    fn sort(&mut self) {
        self.colors.sort_by(|a, b| a.x.total_cmp(&b.x));
        self.opacity.sort_by(|a, b| a.x.total_cmp(&b.x));
    }

    /// The colour at `x`.
    pub fn color_at(&self, x: f32) -> [f32; 3] {
        let pts: Vec<(f32, [f32; 3])> = self.colors.iter().map(|p| (p.x, p.rgb)).collect();
        interpolate(&pts, x)
    }

    /// The opacity at `x`.
    pub fn opacity_at(&self, x: f32) -> f32 {
        let pts: Vec<(f32, [f32; 1])> = self.opacity.iter().map(|p| (p.x, [p.a])).collect();
        interpolate(&pts, x)[0]
    }

    /// Checks the invariants a file or an edit must keep: non-empty lists,
    /// finite values within 0..1, sorted positions.
    pub fn validate(&self) -> Result<(), TfFileError> {
        let bad = |what: String| Err(TfFileError::Invalid(what));
        if self.colors.is_empty() || self.opacity.is_empty() {
            return bad("a transfer function needs a colour and an opacity point".into());
        }
        let unit = |v: f32| (0.0..=1.0).contains(&v);
        for (i, p) in self.colors.iter().enumerate() {
            if !unit(p.x) || !p.rgb.iter().all(|&c| unit(c)) {
                return bad(format!("colour point {i} is outside 0..1: {p:?}"));
            }
        }
        for (i, p) in self.opacity.iter().enumerate() {
            if !unit(p.x) || !unit(p.a) {
                return bad(format!("opacity point {i} is outside 0..1: {p:?}"));
            }
        }
        let sorted = |xs: Vec<f32>| xs.windows(2).all(|w| w[0] <= w[1]);
        if !sorted(self.colors.iter().map(|p| p.x).collect())
            || !sorted(self.opacity.iter().map(|p| p.x).collect())
        {
            return bad("control points are not sorted by position".into());
        }
        Ok(())
    }

    /// The renderer's table: `n` entries, entry `i` at `i / (n - 1)`.
    pub fn to_table(&self, n: usize) -> Result<TransferFunction, TfFileError> {
        self.validate()?;
        let entries = (0..n.max(2))
            .map(|i| {
                let x = i as f32 / (n.max(2) - 1) as f32;
                let [r, g, b] = self.color_at(x);
                [r, g, b, self.opacity_at(x)]
            })
            .collect();
        Ok(TransferFunction::try_from_entries(entries)?)
    }

    /// The opacity point nearest to `(x, a)` within `radius` pixels, where one
    /// unit of `x` is `sx` pixels and one unit of opacity `sy` pixels.
    pub fn hit_opacity(&self, x: f32, a: f32, sx: f32, sy: f32, radius: f32) -> Option<usize> {
        nearest(
            self.opacity
                .iter()
                .map(|p| ((p.x - x) * sx, (p.a - a) * sy)),
            radius,
        )
    }

    /// The colour point nearest to `x` within `radius` pixels (colour points
    /// sit on a strip: only the position counts).
    pub fn hit_color(&self, x: f32, sx: f32, radius: f32) -> Option<usize> {
        nearest(self.colors.iter().map(|p| ((p.x - x) * sx, 0.0)), radius)
    }

    /// Adds an opacity point, keeping the list sorted; returns its index.
    pub fn add_opacity(&mut self, x: f32, a: f32) -> usize {
        let p = OpacityPoint {
            x: clamp01(x),
            a: clamp01(a),
        };
        let i = self.opacity.partition_point(|q| q.x <= p.x);
        self.opacity.insert(i, p);
        i
    }

    /// Adds a colour point with the colour already shown there; returns its index.
    pub fn add_color(&mut self, x: f32) -> usize {
        let x = clamp01(x);
        let rgb = self.color_at(x);
        let i = self.colors.partition_point(|q| q.x <= x);
        self.colors.insert(i, ColorPoint { x, rgb });
        i
    }

    /// Moves opacity point `i` towards `(x, a)`, clamped between its
    /// neighbours (points never pass each other) and to 0..1.
    pub fn move_opacity(&mut self, i: usize, x: f32, a: f32) {
        let Some(&p) = self.opacity.get(i) else {
            return;
        };
        let lo = i.checked_sub(1).map_or(0.0, |j| self.opacity[j].x);
        let hi = self.opacity.get(i + 1).map_or(1.0, |q| q.x);
        self.opacity[i] = OpacityPoint {
            x: clamp_finite(x, lo, hi, p.x),
            a: clamp_finite(a, 0.0, 1.0, p.a),
        };
    }

    /// Moves colour point `i` to `x`, clamped between its neighbours.
    pub fn move_color(&mut self, i: usize, x: f32) {
        let Some(&p) = self.colors.get(i) else { return };
        let lo = i.checked_sub(1).map_or(0.0, |j| self.colors[j].x);
        let hi = self.colors.get(i + 1).map_or(1.0, |q| q.x);
        self.colors[i].x = clamp_finite(x, lo, hi, p.x);
    }

    /// Sets colour point `i`'s colour (clamped to 0..1; non-finite ignored).
    pub fn set_color(&mut self, i: usize, rgb: [f32; 3]) {
        if let Some(p) = self.colors.get_mut(i) {
            for (c, v) in p.rgb.iter_mut().zip(rgb) {
                *c = clamp_finite(v, 0.0, 1.0, *c);
            }
        }
    }

    /// Removes opacity point `i` unless it is the last one left.
    pub fn remove_opacity(&mut self, i: usize) -> bool {
        let ok = self.opacity.len() > 1 && i < self.opacity.len();
        if ok {
            self.opacity.remove(i);
        }
        ok
    }

    /// Removes colour point `i` unless it is the last one left.
    pub fn remove_color(&mut self, i: usize) -> bool {
        let ok = self.colors.len() > 1 && i < self.colors.len();
        if ok {
            self.colors.remove(i);
        }
        ok
    }

    /// The model as pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default()
    }

    /// Parses and validates JSON (`path` names it in errors).
    pub fn from_json(text: &str, path: &std::path::Path) -> Result<TfModel, TfFileError> {
        let m: TfModel = serde_json::from_str(text).map_err(|source| TfFileError::Json {
            path: path.to_owned(),
            source,
        })?;
        m.validate()?;
        Ok(m)
    }

    /// Writes the model to a JSON file.
    pub fn save(&self, path: &std::path::Path) -> Result<(), TfFileError> {
        std::fs::write(path, self.to_json()).map_err(|source| TfFileError::Io {
            path: path.to_owned(),
            source,
        })
    }

    /// Reads and validates a JSON file.
    pub fn load(path: &std::path::Path) -> Result<TfModel, TfFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| TfFileError::Io {
            path: path.to_owned(),
            source,
        })?;
        TfModel::from_json(&text, path)
    }
}

fn clamp01(v: f32) -> f32 {
    clamp_finite(v, 0.0, 1.0, 0.0)
}

/// `v` clamped to `lo..=hi`, or `fallback` when `v` is not finite.
fn clamp_finite(v: f32, lo: f32, hi: f32, fallback: f32) -> f32 {
    if v.is_finite() {
        v.clamp(lo, hi)
    } else {
        fallback
    }
}

/// The index of the offset nearest the origin within `radius`.
fn nearest(offsets: impl Iterator<Item = (f32, f32)>, radius: f32) -> Option<usize> {
    offsets
        .map(|(dx, dy)| (dx * dx + dy * dy).sqrt())
        .enumerate()
        .filter(|&(_, d)| d <= radius)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const CT: [f32; 2] = [-1024.0, 2986.0];

    #[test]
    fn interpolation_is_linear_between_points_and_held_outside() {
        let m = TfModel {
            colors: vec![
                ColorPoint {
                    x: 0.2,
                    rgb: [1.0, 0.0, 0.0],
                },
                ColorPoint {
                    x: 0.6,
                    rgb: [0.0, 0.0, 1.0],
                },
            ],
            opacity: vec![
                OpacityPoint { x: 0.5, a: 0.0 },
                OpacityPoint { x: 0.7, a: 0.8 },
            ],
        };
        assert_eq!(m.color_at(0.0), [1.0, 0.0, 0.0]);
        assert_eq!(m.color_at(1.0), [0.0, 0.0, 1.0]);
        let mid = m.color_at(0.4);
        assert!((mid[0] - 0.5).abs() < 1e-6 && (mid[2] - 0.5).abs() < 1e-6);
        assert_eq!(m.opacity_at(0.3), 0.0);
        assert!((m.opacity_at(0.6) - 0.4).abs() < 1e-6);
        assert_eq!(m.opacity_at(0.9), 0.8);
    }

    /// The editor's table equals the library's own sampling of the same points
    /// when colour and opacity share positions (the harness's bone TF).
    #[test]
    fn table_matches_the_library_sampling() {
        let m = TfModel::preset(TfPreset::CtBone, CT);
        let hu = |v: f32| (v + 1024.0) / 4010.0;
        // Shared positions: drop the first colour point.
        let m = TfModel {
            colors: m.colors[1..].to_vec(),
            ..m
        };
        let ours = m.to_table(512).unwrap();
        let lib = TransferFunction::from_points(
            &[
                (hu(250.0), [0.9, 0.85, 0.75, 0.0]),
                (hu(600.0), [1.0, 0.95, 0.85, 1.0]),
            ],
            512,
        );
        for (a, b) in ours.entries().iter().zip(lib.entries()) {
            for k in 0..4 {
                assert!((a[k] - b[k]).abs() < 1e-5, "{a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn hit_testing_picks_the_nearest_within_the_radius() {
        let m = TfModel::preset(TfPreset::Grey, CT);
        // Points at (0, 0) and (1, 0.5); a 200 x 100 px editor.
        assert_eq!(m.hit_opacity(0.01, 0.02, 200.0, 100.0, 6.0), Some(0));
        assert_eq!(m.hit_opacity(0.99, 0.48, 200.0, 100.0, 6.0), Some(1));
        assert_eq!(m.hit_opacity(0.5, 0.25, 200.0, 100.0, 6.0), None);
        // 0.04 * 200 = 8 px: outside a 6 px radius, inside 10.
        assert_eq!(m.hit_opacity(0.04, 0.0, 200.0, 100.0, 6.0), None);
        assert_eq!(m.hit_opacity(0.04, 0.0, 200.0, 100.0, 10.0), Some(0));
        assert_eq!(m.hit_color(0.97, 200.0, 8.0), Some(1));
        assert_eq!(m.hit_color(0.5, 200.0, 8.0), None);
    }

    #[test]
    fn the_last_point_of_a_list_stays() {
        let mut m = TfModel::preset(TfPreset::Grey, CT);
        assert!(m.remove_opacity(0));
        assert!(!m.remove_opacity(0));
        assert!(m.remove_color(1));
        assert!(!m.remove_color(0));
        assert!(!m.remove_color(7));
        assert!(m.validate().is_ok());
        assert!(m.to_table(16).is_ok());
    }

    #[test]
    fn json_round_trips_and_bad_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tf.json");
        let m = TfModel::preset(TfPreset::CtSoft, CT);
        m.save(&path).unwrap();
        assert_eq!(TfModel::load(&path).unwrap(), m);
        let p = std::path::Path::new("x.json");
        assert!(matches!(
            TfModel::from_json("{", p),
            Err(TfFileError::Json { .. })
        ));
        let empty = r#"{"colors": [], "opacity": [{"x": 0.5, "a": 1.0}]}"#;
        assert!(matches!(
            TfModel::from_json(empty, p),
            Err(TfFileError::Invalid(_))
        ));
        let outside =
            r#"{"colors": [{"x": 0.5, "rgb": [2, 0, 0]}], "opacity": [{"x": 0.5, "a": 1.0}]}"#;
        assert!(matches!(
            TfModel::from_json(outside, p),
            Err(TfFileError::Invalid(_))
        ));
        let unsorted = r#"{"colors": [{"x": 0.5, "rgb": [1, 0, 0]}], "opacity": [{"x": 0.5, "a": 1.0}, {"x": 0.1, "a": 0}]}"#;
        assert!(matches!(
            TfModel::from_json(unsorted, p),
            Err(TfFileError::Invalid(_))
        ));
        assert!(matches!(
            TfModel::load(&dir.path().join("none.json")),
            Err(TfFileError::Io { .. })
        ));
    }

    #[test]
    fn presets_are_valid_and_named() {
        for p in TfPreset::ALL {
            let m = TfModel::preset(p, CT);
            assert!(m.validate().is_ok(), "{p:?}");
            assert_eq!(TfPreset::parse(p.name()), Some(p));
            // Every preset shows something.
            assert!(m.opacity.iter().any(|o| o.a > 0.0), "{p:?}");
        }
    }

    #[derive(Debug, Clone)]
    enum Edit {
        AddO(f32, f32),
        AddC(f32),
        MoveO(usize, f32, f32),
        MoveC(usize, f32),
        RemoveO(usize),
        RemoveC(usize),
        Color(usize, [f32; 3]),
    }

    fn edit() -> impl Strategy<Value = Edit> {
        let v = -0.5f32..1.5;
        prop_oneof![
            (v.clone(), v.clone()).prop_map(|(x, a)| Edit::AddO(x, a)),
            v.clone().prop_map(Edit::AddC),
            (0usize..8, v.clone(), v.clone()).prop_map(|(i, x, a)| Edit::MoveO(i, x, a)),
            (0usize..8, v.clone()).prop_map(|(i, x)| Edit::MoveC(i, x)),
            (0usize..8).prop_map(Edit::RemoveO),
            (0usize..8).prop_map(Edit::RemoveC),
            (0usize..8, v.clone(), v.clone(), v).prop_map(|(i, r, g, b)| Edit::Color(i, [r, g, b])),
        ]
    }

    proptest! {
        /// Any sequence of edits keeps the model valid (sorted, non-empty,
        /// within 0..1), and its table samples the interpolants exactly.
        #[test]
        fn edits_keep_the_model_valid(edits in proptest::collection::vec(edit(), 0..60)) {
            let mut m = TfModel::preset(TfPreset::Mri, CT);
            for e in &edits {
                match *e {
                    Edit::AddO(x, a) => { m.add_opacity(x, a); }
                    Edit::AddC(x) => { m.add_color(x); }
                    Edit::MoveO(i, x, a) => m.move_opacity(i, x, a),
                    Edit::MoveC(i, x) => m.move_color(i, x),
                    Edit::RemoveO(i) => { m.remove_opacity(i); }
                    Edit::RemoveC(i) => { m.remove_color(i); }
                    Edit::Color(i, c) => m.set_color(i, c),
                }
                prop_assert!(m.validate().is_ok(), "{e:?}: {:?}", m.validate());
            }
            let t = m.to_table(33).unwrap();
            for (i, e) in t.entries().iter().enumerate() {
                let x = i as f32 / 32.0;
                prop_assert!((e[3] - m.opacity_at(x)).abs() < 1e-6);
                let c = m.color_at(x);
                prop_assert!((0..3).all(|k| (e[k] - c[k]).abs() < 1e-6));
            }
        }

        /// Adding a point where the curve already is leaves the curve unchanged
        /// (for a colour point, exactly the colour shown there).
        #[test]
        fn adding_on_the_curve_keeps_it(x in 0.0f32..1.0, probe in 0.0f32..1.0) {
            let mut m = TfModel::preset(TfPreset::CtSoft, CT);
            let before = (m.color_at(probe), m.opacity_at(probe));
            let a = m.opacity_at(x);
            m.add_opacity(x, a);
            m.add_color(x);
            let after = (m.color_at(probe), m.opacity_at(probe));
            prop_assert!((before.1 - after.1).abs() < 1e-5);
            prop_assert!((0..3).all(|k| (before.0[k] - after.0[k]).abs() < 1e-5));
        }

        /// The hit point is within the radius and no other point is nearer.
        #[test]
        fn hit_is_the_nearest(x in 0.0f32..1.0, a in 0.0f32..1.0, r in 1.0f32..60.0) {
            let m = TfModel::preset(TfPreset::CtSoft, CT);
            let d = |p: &OpacityPoint| (((p.x - x) * 300.0).powi(2) + ((p.a - a) * 120.0).powi(2)).sqrt();
            match m.hit_opacity(x, a, 300.0, 120.0, r) {
                Some(i) => {
                    prop_assert!(d(&m.opacity[i]) <= r);
                    prop_assert!(m.opacity.iter().all(|p| d(p) >= d(&m.opacity[i])));
                }
                None => prop_assert!(m.opacity.iter().all(|p| d(p) > r)),
            }
        }
    }
}
