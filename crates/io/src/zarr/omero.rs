//! OME-Zarr's `omero` metadata (transitional in NGFF 0.4 and 0.5, written by
//! OMERO, ome-zarr-py, bioformats2raw and napari): one entry per channel
//! with a `label`, a `color` (hex `"RRGGBB"`), a `window` (`start` and `end`
//! in data values, `min` and `max` of the data) and `active`. Read into a
//! [`ChannelInfo`] per channel; a field that is malformed is ignored with a
//! warning, never an error (it is display metadata).

use crate::ChannelInfo;
use serde_json::Value;

/// The [`ChannelInfo`] of the channels of an `omero` object (`None`:
/// absent) for an image of `count` channels: at most `count` entries, in
/// order (a channel past the end has the default), and the warnings for
/// what was ignored.
pub(super) fn channel_info(omero: Option<&Value>, count: u64) -> (Vec<ChannelInfo>, Vec<String>) {
    let n = usize::try_from(count).unwrap_or(usize::MAX);
    let mut warnings = Vec::new();
    let mut info = Vec::new();
    let list = match omero {
        None => None,
        Some(o) => match o.get("channels") {
            Some(Value::Array(l)) => Some(l),
            None => None,
            Some(other) => {
                warnings.push(format!(
                    "omero: channels is {}, not a list: ignored",
                    short(other)
                ));
                None
            }
        },
    };
    if let Some(list) = list {
        if list.len() as u64 != count {
            warnings.push(format!(
                "omero lists {} channels, the image has {count}: {}",
                list.len(),
                if (list.len() as u64) < count {
                    "the others have no metadata"
                } else {
                    "the extra entries are ignored"
                }
            ));
        }
        for (i, c) in list.iter().take(n).enumerate() {
            info.push(one(i, c, &mut warnings));
        }
    }
    (info, warnings)
}

/// A value for a warning, at most 40 characters.
fn short(v: &Value) -> String {
    let s = v.to_string();
    if s.chars().count() > 40 {
        format!("{}...", s.chars().take(40).collect::<String>())
    } else {
        s
    }
}

fn one(i: usize, c: &Value, warnings: &mut Vec<String>) -> ChannelInfo {
    let mut info = ChannelInfo::default();
    let Some(c) = c.as_object() else {
        warnings.push(format!(
            "omero: channel {i} is {}, not an object: ignored",
            short(c)
        ));
        return info;
    };
    let mut warn = |field: &str, v: &Value, what: &str| {
        warnings.push(format!(
            "omero: channel {i}'s {field} is {}, {what}: ignored",
            short(v)
        ));
    };
    match c.get("label") {
        None | Some(Value::Null) => {}
        Some(Value::String(s)) => info.label = Some(s.clone()),
        Some(v) => warn("label", v, "not a string"),
    }
    match c.get("color") {
        None | Some(Value::Null) => {}
        Some(v) => match v.as_str().and_then(hex_color) {
            Some(rgb) => info.color = Some(rgb),
            None => warn("color", v, "not a hex colour \"RRGGBB\""),
        },
    }
    match c.get("window") {
        None | Some(Value::Null) => {}
        Some(w) => {
            let num = |k: &str| {
                w.get(k)
                    .and_then(Value::as_f64)
                    .map(|x| x as f32)
                    .filter(|x| x.is_finite())
            };
            match (num("start"), num("end")) {
                (Some(s), Some(e)) if s <= e => info.window = Some([s, e]),
                (Some(_), Some(_)) => warn("window", w, "its start above its end"),
                _ => warn("window", w, "without a numeric start and end"),
            }
        }
    }
    match c.get("active") {
        None | Some(Value::Null) => {}
        Some(Value::Bool(b)) => info.active = *b,
        Some(v) => warn("active", v, "not true or false"),
    }
    info
}

/// `"RRGGBB"` (an optional `#` before it) as RGB 0..1.
pub(crate) fn hex_color(s: &str) -> Option<[f32; 3]> {
    let h = s.trim().strip_prefix('#').unwrap_or(s.trim());
    if h.len() != 6 || !h.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let byte = |k: usize| u8::from_str_radix(&h[2 * k..2 * k + 2], 16).ok();
    Some([
        byte(0)? as f32 / 255.0,
        byte(1)? as f32 / 255.0,
        byte(2)? as f32 / 255.0,
    ])
}

/// `rgb` (0..1) as `"RRGGBB"`.
pub(super) fn hex_string(rgb: [f32; 3]) -> String {
    rgb.iter()
        .map(|&v| format!("{:02X}", (v.clamp(0.0, 1.0) * 255.0).round() as u8))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn fields_are_read_and_bad_ones_ignored_with_a_warning() {
        let o = json!({"channels": [
            {"label": "DAPI", "color": "0000FF", "window": {"start": 10, "end": 200.5, "min": 0, "max": 255}, "active": false},
            {"label": 7, "color": "GG0000", "window": {"start": "a", "end": 3}, "active": "yes"},
            {"color": "#ff8000", "window": {"start": 5, "end": 1}},
            "nonsense"
        ]});
        let (info, w) = channel_info(Some(&o), 4);
        assert_eq!(
            info[0],
            ChannelInfo {
                label: Some("DAPI".into()),
                color: Some([0.0, 0.0, 1.0]),
                window: Some([10.0, 200.5]),
                active: false
            }
        );
        assert_eq!(info[1], ChannelInfo::default());
        assert_eq!(info[2].color, Some([1.0, 128.0 / 255.0, 0.0]));
        assert_eq!(info[2].window, None);
        assert_eq!(info[3], ChannelInfo::default());
        // label, color, window, active of channel 1; window of 2; channel 3
        assert_eq!(w.len(), 6, "{w:?}");
        assert!(w[0].contains("channel 1's label"), "{w:?}");
        assert!(w.iter().any(|l| l.contains("channel 3")), "{w:?}");
    }

    #[test]
    fn absent_or_short_metadata_gives_defaults() {
        let (info, w) = channel_info(None, 3);
        assert!(info.is_empty());
        assert!(w.is_empty());
        let (info, w) = channel_info(Some(&json!({"channels": [{"label": "a"}]})), 2);
        assert_eq!(info.len(), 1);
        assert_eq!(info[0].label.as_deref(), Some("a"));
        assert_eq!(w.len(), 1, "{w:?}");
        let (_, w) = channel_info(Some(&json!({"channels": 5})), 1);
        assert_eq!(w.len(), 1, "{w:?}");
    }

    #[test]
    fn hex_colours_round_trip() {
        assert_eq!(hex_color("00FF00"), Some([0.0, 1.0, 0.0]));
        assert_eq!(hex_color("00ff0"), None);
        assert_eq!(hex_color("+0FF00"), None);
        assert_eq!(hex_string([1.0, 0.0, 128.0 / 255.0]), "FF0080");
    }
}
