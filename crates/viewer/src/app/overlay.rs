//! A label map over the image (`--overlay FILE`, the script's `overlay`
//! lines): loaded whole, placed where the two files say (their placements
//! when both give one, else both from the grid's corner at their spacing),
//! drawn in the image's rays by the renderer's overlay; its table is edited
//! in the Labels panel, and a click selects the label under it.

use super::*;
use crate::script::OverlayAction;
use brickray::{LabelOverlay, OverlayMode, OverlayStyle, Volume, overlay_transform};

/// The label map drawn over the image.
#[derive(Debug)]
pub(super) struct OverlayLayer {
    pub(super) path: PathBuf,
    pub(super) volume: Arc<Volume>,
    /// Image texture coordinates to the label map's.
    pub(super) image_to_labels: glam::DMat4,
    pub(super) style: OverlayStyle,
}

/// Where a volume lies in millimetres: the file's placement when it gives
/// one, else the grid from the origin at its spacing.
fn physical_frame(path: Option<&Path>, desc: &VolumeDesc) -> VolumeFrame {
    let placed = path
        .and_then(|p| brickray::io::open(p).ok())
        .and_then(|r| r.placement())
        .map(|p| p.frame(desc.dims));
    placed.unwrap_or_else(|| {
        let size =
            glam::UVec3::from_array(desc.dims).as_vec3() * glam::Vec3::from_array(desc.spacing);
        VolumeFrame::new(glam::Mat4::from_scale(size), desc.dims)
    })
}

/// The finest level of the store at `path` that fits one texture (`side`
/// voxels a side) and 256 MiB, read whole (`brickray::core::level_volume`),
/// and a note when it is not the finest.
fn store_level(path: &Path, side: u32) -> Result<(Volume, Option<String>), String> {
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let store = brickray::store::open(path).map_err(|e| err(&e))?;
    let layout = store.layout();
    let size = layout.dtype().size() as u64;
    let fits = |l: u8| {
        let d = layout.level_dims(l);
        d.iter().all(|&v| v <= side)
            && d.iter().map(|&v| v as u64).product::<u64>() * size <= 256 << 20
    };
    let finest = layout.levels - 1;
    let level = (0..=finest).rev().find(|&l| fits(l)).unwrap_or(0);
    let note = (level < finest).then(|| {
        format!(
            "overlay: level {level} of {} ({:?} voxels) fits one texture",
            path.display(),
            layout.level_dims(level)
        )
    });
    let v = brickray::core::level_volume(&store, level).map_err(|e| err(&e))?;
    Ok((v, note))
}

impl ViewerApp {
    /// Reads the label map at `path` and draws it over the image shown.
    pub(super) fn open_overlay(
        &mut self,
        frame: &eframe::Frame,
        path: &Path,
    ) -> Result<(), String> {
        let shown = self.shown.as_ref().ok_or("overlay: no image is shown")?;
        if shown.desc.kind.is_labels() {
            return Err("overlay: the volume shown is a label map (open an image first)".into());
        }
        let mut volume = if path.extension().is_some_and(|e| e == "brs") {
            let (v, note) = store_level(path, self.open_opts.max_3d_side)?;
            self.messages.extend(note);
            v
        } else {
            brickray::io::read_volume(path).map_err(|e| format!("{}: {e}", path.display()))?
        };
        if !volume.desc().kind.is_labels() {
            volume = brickray::core::labels::into_labels(volume)
                .map_err(|e| format!("{}: {e}", path.display()))?;
        }
        let image_path = match &shown.input {
            Input::Path(p) => Some(p.as_path()),
            _ => None,
        };
        let image = physical_frame(image_path, &shown.desc);
        let labels = physical_frame(Some(path), volume.desc());
        // An OME-Zarr label image's own colours, else a table beside it.
        let (table, note) = match brickray::io::zarr::OmeZarr::open(path)
            .ok()
            .and_then(|z| z.label_table())
        {
            Some(t) => (t, Some(format!("label colours from {}", path.display()))),
            None => crate::source::label_table_beside(&Input::Path(path.to_path_buf())),
        };
        let layer = OverlayLayer {
            path: path.to_path_buf(),
            volume: Arc::new(volume),
            image_to_labels: overlay_transform(&image, &labels),
            style: self
                .label_overlay
                .as_ref()
                .map_or(OverlayStyle::default(), |o| o.style),
        };
        self.label_ids = brickray::core::labels::labels_present(&layer.volume);
        self.labels = Some(table);
        if let Some(n) = note {
            self.messages.push(n);
        }
        self.messages.push(format!(
            "overlay {} ({} labels) over {}",
            path.display(),
            self.label_ids.len(),
            shown.input.name()
        ));
        self.label_overlay = Some(layer);
        self.upload_overlay(frame)
    }

    /// An OME-Zarr image with label images (`labels/`): the first is drawn
    /// over it, and the message names them all.
    pub(super) fn overlay_zarr_labels(&mut self, frame: &eframe::Frame) -> Result<(), String> {
        let Some(Input::Path(root)) = self.shown.as_ref().map(|s| s.input.clone()) else {
            return Ok(());
        };
        let Ok(zarr) = brickray::io::zarr::OmeZarr::open(&root) else {
            return Ok(());
        };
        let names = zarr.label_groups().map_err(|e| e.to_string())?;
        let Some(first) = names.first() else {
            return Ok(());
        };
        self.messages.push(format!(
            "label images: {} (the script's `overlay {}/labels/NAME` draws another)",
            names.join(", "),
            root.display()
        ));
        self.open_overlay(frame, &root.join("labels").join(first))
    }

    /// Draws the overlay (after it or the renderer changed).
    pub(super) fn upload_overlay(&mut self, frame: &eframe::Frame) -> Result<(), String> {
        let (Some(o), Some(table)) = (&self.label_overlay, &self.labels) else {
            return Ok(());
        };
        let overlay = LabelOverlay {
            labels: &o.volume,
            image_to_labels: o.image_to_labels,
            table,
            style: o.style,
        };
        // The 3D view and the four views' slices.
        self.with_gpu(frame, |d, q, r| {
            r.renderer.set_overlay(d, q, Some(&overlay))?;
            for s in &mut r.slices {
                s.set_overlay(d, q, Some(&overlay))?;
            }
            Ok::<(), brickray::RenderError>(())
        })
        .ok_or("no GPU")?
        .map_err(|e| format!("overlay: {e}"))
    }

    /// Removes the overlay.
    pub(super) fn remove_overlay(&mut self, frame: &eframe::Frame) {
        if self.label_overlay.take().is_some() {
            self.labels = None;
            self.label_ids.clear();
            self.with_gpu(frame, |d, q, r| {
                for v in std::iter::once(&mut r.renderer).chain(&mut r.slices) {
                    let _ = v.set_overlay(d, q, None);
                }
            });
        }
    }

    /// A script's `overlay ...` line.
    pub(super) fn overlay_action(
        &mut self,
        frame: &eframe::Frame,
        a: OverlayAction,
    ) -> Result<(), String> {
        match a {
            OverlayAction::Open(path) => return self.open_overlay(frame, &path),
            OverlayAction::Off => self.remove_overlay(frame),
            OverlayAction::Opacity(v) => self.set_overlay_style(frame, |s| s.opacity = v)?,
            OverlayAction::Mask(mask) => self.set_overlay_style(frame, |s| {
                s.mode = if mask {
                    OverlayMode::Mask
                } else {
                    OverlayMode::Color
                }
            })?,
        }
        Ok(())
    }

    fn set_overlay_style(
        &mut self,
        frame: &eframe::Frame,
        edit: impl FnOnce(&mut OverlayStyle),
    ) -> Result<(), String> {
        let o = self
            .label_overlay
            .as_mut()
            .ok_or("overlay: none is drawn")?;
        edit(&mut o.style);
        let style = o.style;
        self.with_gpu(frame, |_, q, r| {
            r.renderer.set_overlay_style(q, style)?;
            for s in &mut r.slices {
                s.set_overlay_style(q, style)?;
            }
            Ok::<(), brickray::RenderError>(())
        })
        .ok_or("no GPU")?
        .map_err(|e| format!("overlay: {e}"))
    }

    /// The overlay's controls: mode, opacity, remove.
    pub(super) fn overlay_ui(&mut self, ui: &mut egui::Ui, frame: &eframe::Frame) {
        let Some(o) = self.label_overlay.as_ref() else {
            return;
        };
        ui.label(format!("over the image: {}", o.path.display()));
        let mut style = o.style;
        let mut changed = false;
        ui.horizontal(|ui| {
            changed |= ui
                .radio_value(&mut style.mode, OverlayMode::Color, "colour")
                .changed();
            changed |= ui
                .radio_value(&mut style.mode, OverlayMode::Mask, "inside labels only")
                .changed();
        });
        changed |= ui
            .add(egui::Slider::new(&mut style.opacity, 0.0..=1.0).text("overlay opacity"))
            .changed();
        if changed && let Err(e) = self.set_overlay_style(frame, |s| *s = style) {
            self.messages.push(e);
        }
        if ui.button("remove overlay").clicked() {
            self.remove_overlay(frame);
        }
    }

    /// The label under a pick's image texture point, when an overlay is drawn.
    pub(super) fn overlay_label_at(&self, texture: [f64; 3]) -> Option<Option<u32>> {
        let (o, table) = (self.label_overlay.as_ref()?, self.labels.as_ref()?);
        let overlay = LabelOverlay {
            labels: &o.volume,
            image_to_labels: o.image_to_labels,
            table,
            style: o.style,
        };
        Some(overlay.label_at(texture, self.settings.smooth_labels))
    }
}
