//! The WGSL traversal library parses and validates with naga (the wgpu front end).

use brickray_index::OCTREE_TRAVERSAL_WGSL;

/// A tiny compute entry point that calls every library function, as the ray
/// caster will (the library itself declares no binding and no entry point).
const HARNESS: &str = r#"
@group(0) @binding(0) var<storage, read> index_words: array<u32>;
fn oct_word(i: u32) -> u32 { return index_words[i]; }
fn oct_word_count() -> u32 { return arrayLength(&index_words); }
@group(0) @binding(1) var<storage, read_write> out_words: array<u32>;

@compute @workgroup_size(1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let o = vec3<f32>(-0.5, 0.25, f32(gid.x) * 0.01);
    let d = vec3<f32>(1.0, 0.1, 0.0);
    var st = oct_begin(o, d, 0.0, 1.0e30, 4096u, vec2<u32>(gid.y, OCT_SPLITS_ALL.y));
    var acc = 0u;
    while (oct_next_leaf(&st)) {
        acc = acc + st.hit.data + st.hit.leaf.level + st.hit.tag + bitcast<u32>(st.hit.t_exit - st.hit.t_enter);
    }
    // A segment already clipped to a box inside the cube.
    var si = oct_begin_inside(o, d, 0.5, 1.5, 4096u, OCT_SPLITS_ALL);
    while (oct_next_leaf(&si)) {
        acc = acc + bitcast<u32>(si.hit.t_enter);
    }
    // The building blocks on their own.
    let loc = oct_locate_leaf(OctBox(0u, 0u, vec3<f32>(0.0), vec3<f32>(1.0)), vec3<f32>(0.3), d, OCT_SPLITS_ALL);
    let ex = oct_exit_face(loc.leaf, o, d, vec3<f32>(1.0, 10.0, 0.0));
    let rope = oct_follow_rope(oct_word((loc.word & OCT_PTR_MASK) + 1u + ex.face), loc.leaf, ex.face, OCT_SPLITS_ALL);
    let h = oct_halvings(vec2<u32>(gid.z, gid.x), gid.y);
    let tc = oct_clip_unit_cube(o, d, vec3<f32>(1.0, 10.0, 0.0), 0.0, 1.0);
    out_words[gid.x] = acc + st.status + st.steps + rope.next.node + select(0u, 1u, rope.ok && loc.ok)
        + bitcast<u32>(tc.x + ex.t) + h.x + h.y + h.z + oct_mask(OCT_SPLITS_ALL, gid.z);
}
"#;

fn validate(src: &str) -> naga::valid::ModuleInfo {
    let module = naga::front::wgsl::parse_str(src)
        .unwrap_or_else(|e| panic!("parse error:\n{}", e.emit_to_string(src)));
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    )
    .validate(&module)
    .unwrap_or_else(|e| panic!("validation error:\n{}", e.emit_to_string(src)))
}

#[test]
fn wgsl_library_validates_with_harness() {
    let src = format!("{OCTREE_TRAVERSAL_WGSL}\n{HARNESS}");
    validate(&src);
}

#[test]
fn wgsl_library_validates_after_common_prefix_order() {
    // The ray caster may put the binding after the library: WGSL module scope is
    // order independent.
    let src = format!("{HARNESS}\n{OCTREE_TRAVERSAL_WGSL}");
    validate(&src);
}

/// The WGSL constants match the Rust format constants.
#[test]
fn wgsl_constants_match_format() {
    use brickray_index::format::*;
    let expect = [
        ("OCT_NULL", format!("0x{NULL:08x}u")),
        ("OCT_TAG_SHIFT", format!("{TAG_SHIFT}u")),
        ("OCT_PTR_MASK", format!("0x{PTR_MASK:08x}u")),
        ("OCT_TAG_INNER", format!("{TAG_INNER}u")),
        ("OCT_TAG_EMPTY", format!("{TAG_EMPTY}u")),
        ("OCT_TAG_DATA", format!("{TAG_DATA}u")),
        ("OCT_LEAF_RECORD_WORDS", format!("{LEAF_RECORD_WORDS}u")),
        ("OCT_ROPE_LEVEL_SHIFT", format!("{ROPE_LEVEL_SHIFT}u")),
        ("OCT_ROPE_NODE_MASK", format!("0x{ROPE_NODE_MASK:08x}u")),
        ("OCT_MAX_LEVEL", format!("{MAX_LEVEL}u")),
    ];
    let [lo, hi] = Splits::ALL.gpu_words();
    assert!(OCTREE_TRAVERSAL_WGSL.contains(&format!(
        "const OCT_SPLITS_ALL: vec2<u32> = vec2<u32>(0x{lo:08x}u, 0x{hi:08x}u);"
    )));
    for (name, value) in expect {
        let line = format!("const {name}: u32 = {value};");
        assert!(OCTREE_TRAVERSAL_WGSL.contains(&line), "missing `{line}`");
    }
}
