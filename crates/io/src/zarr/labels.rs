//! OME-Zarr label images (`labels/` groups of an image, NGFF "image-label"):
//! a multiscale image whose group metadata holds `image-label` is a label map
//! (`VolumeKind::Labels`), its `colors` become a label table, and an image
//! lists its label images in `labels/`'s `labels` attribute.

use super::OmeZarr;
use crate::IoError;
use brickray_core::LabelTable;
use serde_json::Value;

/// The colours of an `image-label` object: `(label-value, rgba 0..1)` for
/// each entry of `colors` that has both (others are skipped).
pub(super) fn image_label_colors(label: &Value) -> Vec<(u32, [f32; 4])> {
    label
        .get("colors")
        .and_then(Value::as_array)
        .map(|list| {
            list.iter()
                .filter_map(|c| {
                    let id = c.get("label-value")?.as_u64()?;
                    let rgba = c.get("rgba")?.as_array()?;
                    let v: Vec<f32> = rgba
                        .iter()
                        .filter_map(|x| x.as_f64())
                        .map(|x| (x / 255.0).clamp(0.0, 1.0) as f32)
                        .collect();
                    let id = u32::try_from(id).ok()?;
                    (v.len() == 4).then(|| (id, [v[0], v[1], v[2], v[3]]))
                })
                .collect()
        })
        .unwrap_or_default()
}

impl OmeZarr {
    /// Whether the image is a label image (its metadata holds
    /// `image-label`).
    pub fn is_labels(&self) -> bool {
        self.image_label.is_some()
    }

    /// The label table of a label image: the default table with the
    /// `colors` of its `image-label` (colour and opacity per label value);
    /// `None` for an intensity image.
    pub fn label_table(&self) -> Option<LabelTable> {
        let colors = self.image_label.as_ref()?;
        let mut t = LabelTable::default();
        for &(id, [r, g, b, a]) in colors {
            t.set_color(id, [r, g, b]);
            t.set_opacity(id, a);
        }
        Some(t)
    }

    /// The label images of this image: the names in its `labels/` group's
    /// `labels` attribute (open each as `ROOT/labels/NAME`); empty when it
    /// has none. Names that are not one plain path component are skipped.
    pub fn label_groups(&self) -> Result<Vec<String>, IoError> {
        let attrs = if let Some(v) = self.store.json("labels/zarr.json")? {
            v.get("attributes")
                .and_then(|a| a.get("ome"))
                .cloned()
                .unwrap_or(Value::Null)
        } else if let Some(v) = self.store.json("labels/.zattrs")? {
            v
        } else {
            return Ok(Vec::new());
        };
        Ok(attrs
            .get("labels")
            .and_then(Value::as_array)
            .map(|l| {
                l.iter()
                    .filter_map(Value::as_str)
                    .filter(|n| {
                        !n.is_empty() && *n != "." && *n != ".." && !n.contains(['/', '\\'])
                    })
                    .map(str::to_owned)
                    .collect()
            })
            .unwrap_or_default())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colors_are_read_and_bad_entries_skipped() {
        let v: Value = serde_json::json!({
            "colors": [
                {"label-value": 1, "rgba": [255, 0, 0, 255]},
                {"label-value": 2, "rgba": [0, 255, 0]},
                {"rgba": [0, 0, 255, 255]},
                {"label-value": 3, "rgba": [0, 0, 255, 128]}
            ]
        });
        let c = image_label_colors(&v);
        assert_eq!(c.len(), 2);
        assert_eq!(c[0], (1, [1.0, 0.0, 0.0, 1.0]));
        assert_eq!(c[1].0, 3);
        assert!((c[1].1[3] - 128.0 / 255.0).abs() < 1e-6);
        assert!(image_label_colors(&serde_json::json!({})).is_empty());
    }
}
