//! `--script FILE`: a list of actions run one per frame or more, for tests and
//! reproducible figures. One action per line; `#` starts a comment.
//!
//! ```text
//! open PATH | bulb[:N] | procedural[:N]   open a volume (waits until it is loaded)
//! tf PRESET | tf load FILE.json  transfer function (presets: ct-bone, ct-soft, mri, microscopy, grey)
//! mode dvr | shaded | iso [VALUE] | mip
//! iso VALUE                      isovalue, normalized 0..1
//! step FACTOR                    sampling step in voxels
//! termination T | off            early ray termination at opacity T (0 < T <= 1), or none
//! skipping on | off              empty-space skipping
//! preint on | off                pre-integrated DVR
//! adaptive on | off              DVR's step doubling as the ray's transmittance falls
//! camera orbit YAW PITCH DIST    degrees, degrees, multiple of the home distance
//! camera axis +x|-x|+y|-y|+z|-z  camera reset
//! camera view A|P|L|R|S|I          (an anatomical view: an oriented volume)
//! projection perspective | orthographic
//! overlays on | off              the bounding box and axes, and the slices' crosshair
//! layout four | single           three orthogonal slices and 3D, or the 3D view alone
//! crosshair X Y Z                the four views' crosshair, voxel index coordinates
//! window C W | brain | bone | lung | abdomen | auto | off
//!                                the slices' and MIP's window (raw values, e.g. HU; auto: the
//!                                histogram's 0.5-99.5 percentiles; off: grey over the range, MIP by the TF)
//! background R G B               0..255, behind the volume
//! clip X0 Y0 Z0 X1 Y1 Z1 | clip off   the clip box, texture space 0..1
//! u8 exact | fast                u8 interpolation (reopens the volume)
//! bricks N | off                 out of core: the brick budget (N >= 1 data bricks), or none
//! visibility none | occlusion | rayguided | both
//!                                out of core: where refinement's visibility comes from
//! prediction off | paper | fast | exact
//!                                the isosurface prediction buffer (iso frames)
//! lod geometric [TOL] | visible [BUDGET] | octants [BUDGET]
//!                                out of core: the level-of-detail rule, with its tolerance
//!                                (px per voxel) or error budget (8-bit levels x px, default 255)
//! wait N                         draw N frames
//! wait converged [MAX]           draw until no brick is pending (at most MAX frames, default 600)
//! overlay FILE | off             a label map over the image shown (placed by both files), or none
//! overlay mode color | mask      label colours over the image, or the image inside visible labels only
//! overlay opacity A              0..1
//! channel N visible on | off     a multi-channel volume's channel N (0-based): shown or hidden
//! channel N window LO HI         its window in the channel's raw values
//! channel N color R G B | RRGGBB its colour, 0..255 each (or hex, as OME-Zarr's omero writes it)
//! channel N opacity A            its opacity at and above the window's high end, 0..1
//! channel N iso V                its isovalue in raw values (iso mode)
//! screenshot FILE.png            the volume view, plus FILE.json (camera, viewport)
//! screenshot-window FILE.png     the whole window
//! quit
//! ```

use brickray::core::anatomy::Direction;
use brickray::core::camera::AxisView as Axis;
use brickray::core::tf::TfPreset as Preset;
use std::path::PathBuf;

/// The intensity window of the slices and MIP.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) enum WindowChoice {
    /// None: slices grey over the value range, MIP through the TF.
    #[default]
    Off,
    /// The histogram's 0.5 and 99.5 percentiles.
    Auto,
    /// A CT preset.
    Preset(brickray::CtPreset),
    /// Centre and width in raw values.
    CentreWidth(f64, f64),
}

/// One action.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Action {
    /// Open a volume.
    Open(String),
    /// A preset TF.
    TfPreset(Preset),
    /// A TF file.
    TfLoad(PathBuf),
    /// The render mode (with the isovalue for `iso VALUE`).
    Mode(ModeName, Option<f32>),
    /// The isovalue.
    Iso(f32),
    /// The step factor.
    Step(f32),
    /// Early ray termination's opacity (`None`: off).
    Termination(Option<f32>),
    /// Empty-space skipping.
    Skipping(bool),
    /// Pre-integrated DVR.
    Preint(bool),
    /// DVR's adaptive step (`Accel::adaptive_step`).
    AdaptiveStep(bool),
    /// Orbit: yaw and pitch in degrees, distance as a multiple of the home distance.
    Orbit(f32, f32, f32),
    /// An axis view.
    Axis(Axis),
    /// `camera view A|P|L|R|S|I`: an anatomical view (an oriented volume).
    View(Direction),
    /// The home view.
    Reset,
    /// Orthographic (true) or perspective.
    Orthographic(bool),
    /// Show the bounding box and axes.
    Overlays(bool),
    /// The four-view layout (three orthogonal slices and 3D; true) or the
    /// 3D view alone.
    FourViews(bool),
    /// The crosshair of the four-view layout (voxel index coordinates).
    Crosshair([f64; 3]),
    /// The intensity window of the slices and MIP.
    Window(WindowChoice),
    /// The background colour.
    Background([u8; 3]),
    /// The clip box (texture space).
    Clip([f32; 3], [f32; 3]),
    /// u8 volumes interpolated exactly (true) or from 8-bit texels.
    U8Exact(bool),
    /// The out-of-core brick budget (`None`: the pool's capacity).
    Bricks(Option<u32>),
    /// The out-of-core level-of-detail rule, and the geometric tolerance
    /// when given.
    Lod(brickray::LodMetric, Option<f32>),
    /// The out-of-core visibility policy.
    Visibility(brickray::VisibilityPolicy),
    /// The isosurface prediction buffer.
    Prediction(PredictionChoice),
    /// Draw frames.
    Wait(u32),
    /// Draw until converged, at most this many frames.
    WaitConverged(u32),
    /// Save the view.
    Screenshot(PathBuf),
    /// Save the whole window.
    WindowScreenshot(PathBuf),
    /// Close the viewer.
    Quit,
    /// A label map's table.
    Labels(LabelAction),
    /// A click on the 3D view at view pixel (x, y): on a label map, selects
    /// the label there (a frame or two later).
    Pick([u32; 2]),
    /// A label map over the image.
    Overlay(OverlayAction),
    /// A change to one channel of a multi-channel volume (its index).
    Channel(usize, ChannelEdit),
}

/// What a `channel N ...` script line (or the channel panel) changes of
/// channel N of a multi-channel volume.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum ChannelEdit {
    /// Shown (`true`) or hidden.
    Visible(bool),
    /// The window in the channel's raw values (low <= high).
    Window(f32, f32),
    /// The colour, linear RGB 0..1.
    Color([f32; 3]),
    /// The opacity at and above the window's high end, 0..1.
    Opacity(f32),
    /// The isovalue in the channel's raw values.
    Iso(f32),
}

/// What an `overlay ...` script line does.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum OverlayAction {
    /// Draw this label map over the image shown.
    Open(PathBuf),
    /// Remove the overlay.
    Off,
    /// The overlay's opacity, 0..1.
    Opacity(f32),
    /// The image inside the visible labels only (`true`) or label colours
    /// over the image (`false`).
    Mask(bool),
}

/// What a `labels ...` script line does to the shown label map's table.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum LabelAction {
    /// Show these ids, hide every other one.
    ShowOnly(Vec<u32>),
    /// Show every id (but the background).
    ShowAll,
    /// Select these ids (empty: clear the selection).
    Select(Vec<u32>),
    /// The opacity of labels without their own.
    Opacity(f32),
    /// Load a colour table (mricron .lut or JSON).
    Table(PathBuf),
}

/// Render modes by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ModeName {
    /// DVR.
    Dvr,
    /// DVR with shading.
    Shaded,
    /// Isosurface.
    Iso,
    /// MIP.
    Mip,
}

impl ModeName {
    /// All, in menu order.
    pub(crate) const ALL: [ModeName; 4] = [
        ModeName::Dvr,
        ModeName::Shaded,
        ModeName::Iso,
        ModeName::Mip,
    ];

    /// Its label.
    pub(crate) fn label(self) -> &'static str {
        match self {
            ModeName::Dvr => "DVR",
            ModeName::Shaded => "shaded DVR",
            ModeName::Iso => "isosurface",
            ModeName::Mip => "MIP",
        }
    }
}

/// The error budget of `lod visible` and `lod octants` without one, and of
/// the viewer's error-aware rules when chosen: 255 (8-bit levels x px) lets a
/// fully visible node of full-scale error be as coarse as the geometric rule
/// at 1 px (`brickray::LodMetric::VisibleError`).
pub(crate) const DEFAULT_ERROR_BUDGET: f32 = 255.0;

/// The isosurface prediction buffer's settings the viewer offers
/// (`brickray::Prediction`, docs/prediction.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) enum PredictionChoice {
    /// Every pixel takes the full traversal.
    #[default]
    Off,
    /// Braley et al.'s method (alpha 10, kappa 0.5): fast, with wrong pixels
    /// under motion until the next full refresh.
    Paper,
    /// The paper's method with reprojection and empty-space skipping in the
    /// sparse traversal: the fastest variant measured, with fewer wrong
    /// pixels, not exact.
    Fast,
    /// Reprojection, skipping and the first-hit guard: the full traversal's
    /// image.
    Exact,
}

impl PredictionChoice {
    /// All, in menu order.
    pub(crate) const ALL: [PredictionChoice; 4] = [
        PredictionChoice::Off,
        PredictionChoice::Paper,
        PredictionChoice::Fast,
        PredictionChoice::Exact,
    ];

    /// Its script name and label.
    pub(crate) fn name(self) -> &'static str {
        match self {
            PredictionChoice::Off => "off",
            PredictionChoice::Paper => "paper",
            PredictionChoice::Fast => "fast",
            PredictionChoice::Exact => "exact",
        }
    }

    /// What it does, for the menu.
    pub(crate) fn hover(self) -> &'static str {
        match self {
            PredictionChoice::Off => "every pixel takes the full traversal",
            PredictionChoice::Paper => {
                "the paper's method: fastest to start, wrong pixels under motion \
                 until the next full refresh (every 10 frames)"
            }
            PredictionChoice::Fast => {
                "the paper's method with reprojection and empty-space skipping: \
                 fewer wrong pixels, not exact"
            }
            PredictionChoice::Exact => {
                "reprojection, skipping and the first-hit guard: the full traversal's \
                 image (on a renderer that already skips empty space, not faster)"
            }
        }
    }

    /// The renderer's settings.
    pub(crate) fn settings(self) -> Option<brickray::Prediction> {
        let paper = brickray::Prediction::PAPER;
        match self {
            PredictionChoice::Off => None,
            PredictionChoice::Paper => Some(paper),
            PredictionChoice::Fast => Some(brickray::Prediction {
                reproject: true,
                sparse_ess: true,
                ..paper
            }),
            PredictionChoice::Exact => Some(brickray::Prediction {
                reproject: true,
                sparse_ess: true,
                guard: true,
                ..paper
            }),
        }
    }
}

/// The short name of a level-of-detail rule (the sidecar's, the panel's).
pub(crate) fn lod_rule_name(metric: brickray::LodMetric) -> &'static str {
    match metric {
        brickray::LodMetric::Geometric => "geometric",
        brickray::LodMetric::VisibleError { .. } => "visible error",
        brickray::LodMetric::VisibleOctants { .. } => "visible octants",
    }
}

/// A script line that cannot be run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("script line {line}: {reason}: {text:?}")]
pub(crate) struct ScriptError {
    /// 1-based line number.
    pub(crate) line: usize,
    /// The line.
    pub(crate) text: String,
    /// What is wrong.
    pub(crate) reason: String,
}

/// Parses a script.
pub(crate) fn parse(text: &str) -> Result<Vec<Action>, ScriptError> {
    let mut actions = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let err = |reason: &str| ScriptError {
            line: i + 1,
            text: raw.to_string(),
            reason: reason.to_string(),
        };
        let words: Vec<&str> = line.split_whitespace().collect();
        let num = |s: &str| -> Result<f32, ScriptError> {
            s.parse::<f32>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| err("expected a finite number"))
        };
        let unit = |s: &str| -> Result<f32, ScriptError> {
            num(s).and_then(|v| {
                if (0.0..=1.0).contains(&v) {
                    Ok(v)
                } else {
                    Err(err("expected a value in 0..1"))
                }
            })
        };
        let on_off = |s: &str| match s {
            "on" => Ok(true),
            "off" => Ok(false),
            _ => Err(err("expected on or off")),
        };
        let rest = || line.split_once(char::is_whitespace).map(|r| r.1.trim());
        let action = match words.as_slice() {
            ["open", ..] => {
                Action::Open(rest().ok_or_else(|| err("open needs a path"))?.to_string())
            }
            ["tf", "load", ..] => Action::TfLoad(
                rest()
                    .and_then(|r| r.strip_prefix("load"))
                    .map(str::trim)
                    .filter(|p| !p.is_empty())
                    .ok_or_else(|| err("tf load needs a file"))?
                    .into(),
            ),
            ["tf", name] => {
                Action::TfPreset(Preset::parse(name).ok_or_else(|| err("unknown preset"))?)
            }
            ["mode", "dvr"] => Action::Mode(ModeName::Dvr, None),
            ["mode", "shaded"] => Action::Mode(ModeName::Shaded, None),
            ["mode", "iso"] => Action::Mode(ModeName::Iso, None),
            ["mode", "iso", v] => Action::Mode(ModeName::Iso, Some(unit(v)?)),
            ["mode", "mip"] => Action::Mode(ModeName::Mip, None),
            ["iso", v] => Action::Iso(unit(v)?),
            ["step", v] => {
                let v = num(v)?;
                let (lo, hi) = (
                    brickray::RenderSettings::MIN_STEP_FACTOR,
                    brickray::RenderSettings::MAX_STEP_FACTOR,
                );
                if !(lo..=hi).contains(&v) {
                    return Err(err(&format!("the step must be in {lo}..={hi}")));
                }
                Action::Step(v)
            }
            ["termination", "off"] => Action::Termination(None),
            ["termination", v] => {
                let v = num(v)?;
                if !(v > 0.0 && v <= 1.0) {
                    return Err(err("the termination opacity must be in (0, 1]"));
                }
                Action::Termination(Some(v))
            }
            ["skipping", v] => Action::Skipping(on_off(v)?),
            ["preint", v] => Action::Preint(on_off(v)?),
            ["adaptive", v] => Action::AdaptiveStep(on_off(v)?),
            ["camera", "orbit", y, p, d] => {
                let d = num(d)?;
                if d <= 0.0 {
                    return Err(err("the distance must be > 0"));
                }
                Action::Orbit(num(y)?, num(p)?, d)
            }
            ["camera", "axis", a] => Action::Axis(
                Axis::parse(a).ok_or_else(|| err("expected +x, -x, +y, -y, +z or -z"))?,
            ),
            ["camera", "view", d] => {
                Action::View(Direction::parse(d).ok_or_else(|| err("expected A, P, L, R, S or I"))?)
            }
            ["camera", "reset"] => Action::Reset,
            ["projection", "perspective"] => Action::Orthographic(false),
            ["projection", "orthographic"] => Action::Orthographic(true),
            ["overlays", v] => Action::Overlays(on_off(v)?),
            ["window", "off"] => Action::Window(WindowChoice::Off),
            ["window", "auto"] => Action::Window(WindowChoice::Auto),
            ["window", "brain"] => Action::Window(WindowChoice::Preset(brickray::CtPreset::Brain)),
            ["window", "bone"] => Action::Window(WindowChoice::Preset(brickray::CtPreset::Bone)),
            ["window", "lung"] => Action::Window(WindowChoice::Preset(brickray::CtPreset::Lung)),
            ["window", "abdomen"] => {
                Action::Window(WindowChoice::Preset(brickray::CtPreset::Abdomen))
            }
            ["window", c, w] => {
                let (c, w) = (num(c)? as f64, num(w)? as f64);
                if w <= 0.0 {
                    return Err(err("expected a window width > 0"));
                }
                Action::Window(WindowChoice::CentreWidth(c, w))
            }
            ["overlay", "off"] => Action::Overlay(OverlayAction::Off),
            ["overlay", "mode", "color" | "colour"] => Action::Overlay(OverlayAction::Mask(false)),
            ["overlay", "mode", "mask"] => Action::Overlay(OverlayAction::Mask(true)),
            ["overlay", "opacity", v] => {
                let v = num(v)?;
                if !(0.0..=1.0).contains(&v) {
                    return Err(err("overlay opacity must be within 0..1"));
                }
                Action::Overlay(OverlayAction::Opacity(v))
            }
            ["overlay", path] if !matches!(*path, "mode" | "opacity") => {
                Action::Overlay(OverlayAction::Open(PathBuf::from(path)))
            }
            ["pick", x, y] => {
                let p = |v: &str| {
                    v.parse::<u32>()
                        .map_err(|_| err("expected view pixels x y"))
                };
                Action::Pick([p(x)?, p(y)?])
            }
            ["labels", "show-all"] => Action::Labels(LabelAction::ShowAll),
            ["labels", "select", "none"] => Action::Labels(LabelAction::Select(Vec::new())),
            ["labels", "opacity", v] => {
                let v = num(v)?;
                if !(0.0..=1.0).contains(&v) {
                    return Err(err("expected an opacity in 0..=1"));
                }
                Action::Labels(LabelAction::Opacity(v))
            }
            ["labels", "table", path] => Action::Labels(LabelAction::Table(PathBuf::from(path))),
            ["labels", what @ ("show-only" | "select"), ids @ ..] if !ids.is_empty() => {
                let ids = ids
                    .iter()
                    .map(|v| v.parse::<u32>())
                    .collect::<Result<Vec<u32>, _>>()
                    .map_err(|_| err("expected label ids (integers >= 0)"))?;
                Action::Labels(if *what == "select" {
                    LabelAction::Select(ids)
                } else {
                    LabelAction::ShowOnly(ids)
                })
            }
            ["channel", n, what @ ..] => {
                let c = n
                    .parse::<usize>()
                    .ok()
                    .filter(|&c| c < brickray::core::channels::MAX_CHANNELS)
                    .ok_or_else(|| {
                        err(&format!(
                            "expected a channel index 0..={}",
                            brickray::core::channels::MAX_CHANNELS - 1
                        ))
                    })?;
                let edit = match what {
                    ["visible", v] => ChannelEdit::Visible(on_off(v)?),
                    ["window", lo, hi] => {
                        let (lo, hi) = (num(lo)?, num(hi)?);
                        if lo > hi {
                            return Err(err("the window's low end exceeds its high end"));
                        }
                        ChannelEdit::Window(lo, hi)
                    }
                    ["color" | "colour", hex] => {
                        let byte = |i: usize| {
                            hex.get(i..i + 2)
                                .and_then(|b| u8::from_str_radix(b, 16).ok())
                        };
                        match (hex.len(), byte(0), byte(2), byte(4)) {
                            (6, Some(r), Some(g), Some(b)) => {
                                ChannelEdit::Color([r, g, b].map(|v| f32::from(v) / 255.0))
                            }
                            _ => return Err(err("expected R G B (0..255) or RRGGBB")),
                        }
                    }
                    ["color" | "colour", r, g, b] => {
                        let c = |s: &str| {
                            s.parse::<u8>()
                                .map(|v| f32::from(v) / 255.0)
                                .map_err(|_| err("expected R G B (0..255) or RRGGBB"))
                        };
                        ChannelEdit::Color([c(r)?, c(g)?, c(b)?])
                    }
                    ["opacity", a] => ChannelEdit::Opacity(unit(a)?),
                    ["iso", v] => ChannelEdit::Iso(num(v)?),
                    _ => {
                        return Err(err(
                            "expected channel N visible on|off, window LO HI, color R G B, \
                             opacity A or iso V",
                        ));
                    }
                };
                Action::Channel(c, edit)
            }
            ["layout", "four"] => Action::FourViews(true),
            ["layout", "single"] => Action::FourViews(false),
            ["crosshair", x, y, z] => {
                let f = |v: &str| -> Result<f64, ScriptError> {
                    v.parse::<f64>()
                        .ok()
                        .filter(|v| v.is_finite())
                        .ok_or_else(|| err("expected three finite voxel coordinates"))
                };
                Action::Crosshair([f(x)?, f(y)?, f(z)?])
            }
            ["u8", "exact"] => Action::U8Exact(true),
            ["u8", "fast"] => Action::U8Exact(false),
            ["bricks", "off"] => Action::Bricks(None),
            ["bricks", n] => Action::Bricks(Some(
                n.parse()
                    .ok()
                    .filter(|&n: &u32| n >= 1)
                    .ok_or_else(|| err("expected a brick count >= 1, or off"))?,
            )),
            ["lod", rule, value @ ..] if value.len() <= 1 => {
                let value = value
                    .first()
                    .map(|v| num(v))
                    .transpose()?
                    .map(|v| {
                        if v >= 0.0 {
                            Ok(v)
                        } else {
                            Err(err("expected a tolerance or budget >= 0"))
                        }
                    })
                    .transpose()?;
                let budget = value.unwrap_or(DEFAULT_ERROR_BUDGET);
                match *rule {
                    "geometric" => Action::Lod(brickray::LodMetric::Geometric, value),
                    "visible" => Action::Lod(brickray::LodMetric::VisibleError { budget }, None),
                    "octants" => Action::Lod(brickray::LodMetric::VisibleOctants { budget }, None),
                    _ => return Err(err("expected geometric, visible or octants")),
                }
            }
            ["visibility", name] => Action::Visibility(
                brickray::VisibilityPolicy::ALL
                    .into_iter()
                    .find(|p| p.name() == *name)
                    .ok_or_else(|| err("expected none, occlusion, rayguided or both"))?,
            ),
            ["prediction", name] => Action::Prediction(
                PredictionChoice::ALL
                    .into_iter()
                    .find(|p| p.name() == *name)
                    .ok_or_else(|| err("expected off, paper, fast or exact"))?,
            ),
            ["clip", "off"] => Action::Clip([0.0; 3], [1.0; 3]),
            ["clip", x0, y0, z0, x1, y1, z1] => {
                let lo = [unit(x0)?, unit(y0)?, unit(z0)?];
                let hi = [unit(x1)?, unit(y1)?, unit(z1)?];
                if (0..3).any(|a| lo[a] > hi[a]) {
                    return Err(err("the clip box's minimum exceeds its maximum"));
                }
                Action::Clip(lo, hi)
            }
            ["background", r, g, b] => {
                let c = |s: &str| s.parse::<u8>().map_err(|_| err("expected 0..255"));
                Action::Background([c(r)?, c(g)?, c(b)?])
            }
            ["wait", "converged"] => Action::WaitConverged(600),
            ["wait", "converged", n] => {
                Action::WaitConverged(n.parse().map_err(|_| err("expected a frame count"))?)
            }
            ["wait", n] => Action::Wait(n.parse().map_err(|_| err("expected a frame count"))?),
            ["screenshot-window", ..] => Action::WindowScreenshot(
                rest()
                    .ok_or_else(|| err("screenshot-window needs a file"))?
                    .into(),
            ),
            ["screenshot", ..] => {
                Action::Screenshot(rest().ok_or_else(|| err("screenshot needs a file"))?.into())
            }
            ["quit"] => Action::Quit,
            _ => return Err(err("unknown action")),
        };
        actions.push(action);
    }
    Ok(actions)
}

#[cfg(test)]
mod tests;
