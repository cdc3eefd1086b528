// A label map over the image, in the same ray (group 3; brickray_core::overlay
// is the model, `LabelOverlay::apply` its CPU twin). Both kernels include it;
// without an overlay the group binds a 1-texel stand-in and OVERLAY is 0.

// 0: no overlay; OVERLAY_COLOR, OVERLAY_MASK: brickray_core::OverlayMode.
override OVERLAY: u32 = 0u;
const OVERLAY_COLOR: u32 = 1u;
const OVERLAY_MASK: u32 = 2u;
// Entries of the label table (brickray_core::LABEL_TABLE_ENTRIES).
const OVERLAY_ENTRIES: u32 = 2048u;

struct OverlayParams {
    // Image texture coordinates to the label map's.
    image_to_labels: mat4x4<f32>,
    // The label map's voxel dimensions.
    dims: vec3<f32>,
    // id = texel * id_scale + id_offset (the label encoding's scale and
    // offset times the label value range).
    id_scale: f32,
    id_offset: f32,
    // OverlayStyle::opacity.
    opacity: f32,
    pad0: f32,
    pad1: f32,
}

@group(3) @binding(0) var<uniform> overlay: OverlayParams;
@group(3) @binding(1) var overlay_tex: texture_3d<f32>;
// The label table: straight colour and opacity of id i at texel (i, 0).
@group(3) @binding(2) var overlay_table: texture_2d<f32>;

// The label table's entry of the label under image texture point u (all zero
// outside the label map): nearest, or with SMOOTH_LABELS the heaviest of 8.
fn overlay_label(u: vec3<f32>) -> vec4<f32> {
    let q = (overlay.image_to_labels * vec4<f32>(u, 1.0)).xyz;
    if (any(q < vec3<f32>(0.0)) || any(q >= vec3<f32>(1.0))) {
        return vec4<f32>(0.0);
    }
    let texel = label_texel(overlay_tex, q, overlay.dims);
    let id = clamp(round(texel * overlay.id_scale + overlay.id_offset), 0.0, f32(OVERLAY_ENTRIES - 1u));
    return textureLoad(overlay_table, vec2<i32>(i32(id), 0), 0);
}

// Iso and MIP: colour rgb at image texture point u tinted by the label there
// (colour mode; LabelOverlay::tint).
fn overlay_tint(rgb: vec3<f32>, u: vec3<f32>) -> vec3<f32> {
    if (OVERLAY != OVERLAY_COLOR) {
        return rgb;
    }
    return overlay_apply(vec4<f32>(rgb, 1.0), u).rgb;
}

// The image's sample s (straight colour, opacity) at image texture point u
// with the labels applied (brickray_core::overlay::apply_label).
fn overlay_apply(s: vec4<f32>, u: vec3<f32>) -> vec4<f32> {
    if (OVERLAY == 0u) {
        return s;
    }
    let l = overlay_label(u);
    if (OVERLAY == OVERLAY_MASK) {
        return vec4<f32>(s.rgb, s.a * select(1.0 - overlay.opacity, 1.0, l.a > 0.0));
    }
    return vec4<f32>(mix(s.rgb, l.rgb, l.a * overlay.opacity), s.a);
}
