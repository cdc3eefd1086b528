//! naga validation and reflection of every composed shader against the Rust side.

use super::*;
use crate::backend::incore::VolumeParams;
use crate::composite::CompositeUniforms;
use crate::frame::{FrameFlags, FrameUniforms};
use crate::group2::volume_layout_entries;
use crate::kernels::{KernelMode, OVERRIDES, WORKGROUP};
use crate::predict::{PredictUniforms, ReprojectUniforms, TraversalClass};
use crate::tf::TfInfo;
use crate::volume::{OocParams, SlotInfo};
use naga::valid::{Capabilities, ValidationFlags, Validator};
use std::collections::BTreeSet;

fn module(name: &str, src: &str) -> naga::Module {
    let module = naga::front::wgsl::parse_str(src)
        .unwrap_or_else(|e| panic!("{name}: parse error:\n{}", e.emit_to_string(src)));
    Validator::new(ValidationFlags::all(), Capabilities::all())
        .validate(&module)
        .unwrap_or_else(|e| panic!("{name}: validation error:\n{}", e.emit_to_string(src)));
    module
}

/// `(member name, byte offset)` of a WGSL struct, and its size.
fn wgsl_struct(m: &naga::Module, name: &str) -> (Vec<(String, u32)>, u32) {
    let (_, ty) = m
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no struct {name}"));
    match &ty.inner {
        naga::TypeInner::Struct { members, span } => (
            members
                .iter()
                .map(|mb| (mb.name.clone().unwrap_or_default(), mb.offset))
                .collect(),
            *span,
        ),
        other => panic!("{name} is not a struct: {other:?}"),
    }
}

/// `(field name, byte offset)` of a Rust struct's fields, in the order given.
macro_rules! rust_fields {
    ($rust:ty, [$($field:ident),* $(,)?]) => {
        vec![$((stringify!($field).to_string(), std::mem::offset_of!($rust, $field) as u32)),*]
    };
}

// (After the macro, which it uses.)
mod channels;
mod permutations;

/// Checks a WGSL struct's members, name by name and offset by offset, and its
/// size against a Rust struct.
fn check_struct(m: &naga::Module, wgsl: &str, rust: Vec<(String, u32)>, size: usize) {
    let (members, span) = wgsl_struct(m, wgsl);
    assert_eq!(
        members, rust,
        "WGSL struct {wgsl} drifted from the Rust side"
    );
    assert_eq!(span as usize, size, "WGSL struct {wgsl} size");
}

fn frame_fields() -> Vec<(String, u32)> {
    rust_fields!(
        FrameUniforms,
        [
            eye_tex,
            near,
            fwd_tex,
            depth_a,
            right_tex,
            depth_b,
            up_tex,
            dt,
            fwd_world,
            step_factor,
            right_world,
            ert_threshold,
            up_world,
            depth_opacity,
            iso_color,
            isovalue,
            normal_mat,
            viewport_origin,
            viewport_size,
            flags,
            iso_refine_steps,
            max_samples,
            max_leaves,
            ambient,
            diffuse,
            specular,
            shininess,
            clip_min,
            clip_pad_a,
            clip_max,
            clip_pad_b,
            window_lo,
            window_hi,
            color_map,
            slab_mode,
            slab_samples,
            slab_dt,
            map_pad_a,
            map_pad_b,
        ]
    )
}

fn kernel_bindings(volume: &[wgpu::BindGroupLayoutEntry]) -> BTreeSet<(u32, u32, &'static str)> {
    rust_bindings(&[
        &crate::frame::layout_entries(),
        &crate::tf::layout_entries(),
        volume,
        &crate::overlay::layout_entries(),
    ])
}

/// The value of a `const NAME: u32` of the module.
fn const_u32(m: &naga::Module, name: &str) -> u32 {
    let (_, c) = m
        .constants
        .iter()
        .find(|(_, c)| c.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no const {name}"));
    match m.global_expressions[c.init] {
        naga::Expression::Literal(naga::Literal::U32(v)) => v,
        ref e => panic!("{name} is not a u32 literal: {e:?}"),
    }
}

/// `(group, binding, kind)` of every resource the module declares.
fn wgsl_bindings(m: &naga::Module) -> BTreeSet<(u32, u32, &'static str)> {
    m.global_variables
        .iter()
        .filter_map(|(_, v)| {
            let b = v.binding.as_ref()?;
            let kind = match v.space {
                naga::AddressSpace::Uniform => "uniform",
                naga::AddressSpace::Storage { access }
                    if access.contains(naga::StorageAccess::STORE) =>
                {
                    "storage_rw"
                }
                naga::AddressSpace::Storage { .. } => "storage",
                _ => match &m.types[v.ty].inner {
                    naga::TypeInner::Sampler { .. } => "sampler",
                    naga::TypeInner::Image {
                        class: naga::ImageClass::Storage { .. },
                        ..
                    } => "storage_texture",
                    naga::TypeInner::Image { .. } => "texture",
                    other => panic!("unexpected resource {other:?}"),
                },
            };
            Some((b.group, b.binding, kind))
        })
        .collect()
}

/// The same from the Rust layouts, group by group.
fn rust_bindings(groups: &[&[wgpu::BindGroupLayoutEntry]]) -> BTreeSet<(u32, u32, &'static str)> {
    let mut out = BTreeSet::new();
    for (g, entries) in groups.iter().enumerate() {
        for e in entries.iter() {
            let kind = match e.ty {
                wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    ..
                } => "uniform",
                wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: false },
                    ..
                } => "storage_rw",
                wgpu::BindingType::Buffer { .. } => "storage",
                wgpu::BindingType::Sampler(_) => "sampler",
                wgpu::BindingType::StorageTexture { .. } => "storage_texture",
                wgpu::BindingType::Texture { .. } => "texture",
                ref other => panic!("unexpected layout entry {other:?}"),
            };
            out.insert((g as u32, e.binding, kind));
        }
    }
    out
}

fn check_kernel(
    name: &str,
    m: &naga::Module,
    volume: &[wgpu::BindGroupLayoutEntry],
    extra: &[&str],
) {
    // Entry points (the ray caster and the slice view).
    let names: Vec<&str> = m.entry_points.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(
        names,
        [crate::kernels::ENTRY_RAYCAST, crate::kernels::ENTRY_SLICE],
        "{name}"
    );
    check_kernel_common(name, m, volume, extra);
    for (wgsl, mode) in [
        ("SLAB_MAX", crate::slice::SLAB_MAX),
        ("SLAB_MEAN", crate::slice::SLAB_MEAN),
    ] {
        assert_eq!(const_u32(m, wgsl), mode, "{name}: {wgsl}");
    }
}

/// What every ray-cast kernel shares: workgroup size, the override
/// constants (the shared ones and `extra`), ids, flags and the layouts of
/// groups 0, 1 and 3, and every binding against the Rust layouts (group 2:
/// `volume`).
fn check_kernel_common(
    name: &str,
    m: &naga::Module,
    volume: &[wgpu::BindGroupLayoutEntry],
    extra: &[&str],
) {
    for ep in &m.entry_points {
        assert_eq!(ep.stage, naga::ShaderStage::Compute, "{name}");
        assert_eq!(ep.workgroup_size, [WORKGROUP[0], WORKGROUP[1], 1], "{name}");
    }
    // Overrides, by name.
    let overrides: BTreeSet<String> = m
        .overrides
        .iter()
        .filter_map(|(_, o)| o.name.clone())
        .collect();
    let want: BTreeSet<String> = OVERRIDES
        .iter()
        .chain(extra)
        .map(|s| s.to_string())
        .collect();
    assert_eq!(overrides, want, "{name}: override constants");
    // The tables' rows (TableTexture).
    assert_eq!(const_u32(m, "TABLE_ROW"), crate::gpu::TABLE_ROW, "{name}");
    // Mode ids and flag bits.
    for (wgsl, mode) in KernelMode::ALL {
        assert_eq!(const_u32(m, wgsl), mode as u32, "{name}: {wgsl}");
    }
    for (wgsl, flag) in FrameFlags::ALL {
        assert_eq!(const_u32(m, wgsl), flag.0, "{name}: {wgsl}");
    }
    // Colour map ids and the viridis table (generated from the Rust side).
    for (wgsl, map) in [
        ("MAP_GREY", brickray_core::ColorMap::Grey),
        ("MAP_HOT", brickray_core::ColorMap::Hot),
        ("MAP_VIRIDIS", brickray_core::ColorMap::Viridis),
    ] {
        assert_eq!(const_u32(m, wgsl), map.id(), "{name}: {wgsl}");
    }
    assert_eq!(const_u32(m, "MAP_TF"), 0, "{name}");
    assert_eq!(
        const_u32(m, "VIRIDIS_N") as usize,
        brickray_core::window::VIRIDIS.len(),
        "{name}"
    );
    // Uniform layouts of groups 0 and 1.
    check_struct(
        m,
        "Frame",
        frame_fields(),
        std::mem::size_of::<FrameUniforms>(),
    );
    check_struct(
        m,
        "TfInfo",
        rust_fields!(TfInfo, [count, width, rows, preint_size]),
        std::mem::size_of::<TfInfo>(),
    );
    // The prediction buffer's uniforms and traversal classes (both kernels
    // declare them: group 0 is shared).
    check_struct(
        m,
        "Predict",
        rust_fields!(
            PredictUniforms,
            [
                read_off,
                write_off,
                class_off,
                refresh,
                local_steps,
                sparse_refine,
                sparse_dt,
                reprojected
            ]
        ),
        std::mem::size_of::<PredictUniforms>(),
    );
    for (wgsl, class) in TraversalClass::ALL {
        assert_eq!(const_u32(m, wgsl), class as u32, "{name}: {wgsl}");
    }
    // The overlay's uniforms, table size and mode ids (both kernels).
    check_struct(
        m,
        "OverlayParams",
        rust_fields!(
            crate::overlay::OverlayParams,
            [
                image_to_labels,
                dims,
                id_scale,
                id_offset,
                opacity,
                pad0,
                pad1
            ]
        ),
        std::mem::size_of::<crate::overlay::OverlayParams>(),
    );
    assert_eq!(
        const_u32(m, "OVERLAY_ENTRIES") as usize,
        brickray_core::LABEL_TABLE_ENTRIES,
        "{name}: OVERLAY_ENTRIES"
    );
    for (wgsl, mode) in [
        ("OVERLAY_COLOR", brickray_core::OverlayMode::Color),
        ("OVERLAY_MASK", brickray_core::OverlayMode::Mask),
    ] {
        assert_eq!(
            const_u32(m, wgsl),
            crate::kernels::overlay_id(mode),
            "{name}: {wgsl}"
        );
    }
    // Every binding of every group against the Rust layouts.
    assert_eq!(
        wgsl_bindings(m),
        kernel_bindings(volume),
        "{name}: bindings"
    );
}

#[test]
fn incore_kernel_matches_the_rust_side() {
    let m = module("incore", &incore());
    check_kernel("incore", &m, &crate::backend::incore::layout_entries(), &[]);
    check_struct(
        &m,
        "VolumeParams",
        rust_fields!(
            VolumeParams,
            [
                dims,
                value_scale,
                cells,
                cell_size,
                value_offset,
                pad0,
                pad1,
                pad2
            ]
        ),
        std::mem::size_of::<VolumeParams>(),
    );
}

/// `OocParams` (ooc_volume.wgsl, both out-of-core kernels) against the Rust
/// side.
fn check_ooc_params(m: &naga::Module) {
    check_struct(
        m,
        "OocParams",
        rust_fields!(
            OocParams,
            [
                dims,
                value_scale,
                octree_scale,
                value_offset,
                atlas_size,
                finest_level,
                brick,
                apron,
                stored_side,
                sub_cells,
                splits,
            ]
        ),
        std::mem::size_of::<OocParams>(),
    );
}

#[test]
fn ooc_kernel_matches_the_rust_side() {
    let m = module("ooc", &ooc());
    check_kernel(
        "ooc",
        &m,
        &crate::group2::ooc_single_layout_entries(),
        &[crate::kernels::OCTREE_OVERRIDE],
    );
    // The spread's row mapping uses the core's largest spread.
    let (_, c) = m
        .constants
        .iter()
        .find(|(_, c)| c.name.as_deref() == Some("SPREAD_SIGMA_MAX"))
        .expect("SPREAD_SIGMA_MAX");
    assert!(matches!(
        m.global_expressions[c.init],
        naga::Expression::Literal(naga::Literal::F32(v))
            if v as f64 == brickray_core::tf::spread::SIGMA_MAX
    ));
    check_ooc_params(&m);
    check_struct(
        &m,
        "SlotInfo",
        rust_fields!(SlotInfo, [offset, range]),
        std::mem::size_of::<SlotInfo>(),
    );
}

/// A module of its own with one compute entry point, `main`, on the ray
/// casters' workgroup.
fn check_one_compute_entry(m: &naga::Module) {
    assert_eq!(m.entry_points.len(), 1);
    let ep = &m.entry_points[0];
    assert_eq!(
        (ep.name.as_str(), ep.stage),
        ("main", naga::ShaderStage::Compute)
    );
    assert_eq!(ep.workgroup_size, [WORKGROUP[0], WORKGROUP[1], 1]);
}

#[test]
fn reproject_matches_the_rust_side() {
    let m = module("reproject", REPROJECT);
    check_one_compute_entry(&m);
    check_struct(
        &m,
        "Reproject",
        rust_fields!(
            ReprojectUniforms,
            [
                prev_eye,
                prev_perspective,
                prev_fwd,
                prev_near,
                prev_right,
                pad0,
                prev_up,
                pad1,
                eye,
                perspective,
                fwd,
                near,
                right,
                pad2,
                up,
                pad3,
                size,
                read_off,
                write_off
            ]
        ),
        std::mem::size_of::<ReprojectUniforms>(),
    );
    assert_eq!(
        wgsl_bindings(&m),
        rust_bindings(&[&crate::predict::reproject_layout_entries()])
    );
    // The hit bound matches predict.wgsl's flags.
    assert_eq!(
        const_u32(&m, "HIT_MAX"),
        const_u32(&module("incore", &incore()), "PRED_MISS_BOX")
    );
}

#[test]
fn gradients_match_the_rust_side() {
    use crate::backend::gradients::{GradientParams, WGSL, layout_entries};
    let m = module("gradients", WGSL);
    check_one_compute_entry(&m);
    check_struct(
        &m,
        "GradientParams",
        rust_fields!(
            GradientParams,
            [dims, value_scale, value_offset, pad0, pad1, pad2]
        ),
        std::mem::size_of::<GradientParams>(),
    );
    assert_eq!(wgsl_bindings(&m), rust_bindings(&[&layout_entries()]));
}

#[test]
fn occlusion_matches_the_rust_side() {
    use crate::backend::occlusion::{OcclusionUniforms, WGSL, layout_entries};
    let m = module("occlusion", WGSL);
    let eps: BTreeSet<(String, naga::ShaderStage)> = m
        .entry_points
        .iter()
        .map(|e| (e.name.clone(), e.stage))
        .collect();
    let want: BTreeSet<(String, naga::ShaderStage)> = [
        ("fill_vs", naga::ShaderStage::Vertex),
        ("fill_fs", naga::ShaderStage::Fragment),
        ("box_vs", naga::ShaderStage::Vertex),
    ]
    .into_iter()
    .map(|(n, s)| (n.to_string(), s))
    .collect();
    assert_eq!(eps, want);
    check_struct(
        &m,
        "OcclusionUniforms",
        rust_fields!(OcclusionUniforms, [view_proj]),
        std::mem::size_of::<OcclusionUniforms>(),
    );
    assert_eq!(wgsl_bindings(&m), rust_bindings(&[&layout_entries()]));
}

#[test]
fn composite_matches_the_rust_side() {
    let m = module("composite", COMPOSITE);
    let names: BTreeSet<&str> = m.entry_points.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(names, BTreeSet::from(["vs_main", "fs_main", "fs_color"]));
    check_struct(
        &m,
        "Composite",
        rust_fields!(CompositeUniforms, [origin, pad]),
        std::mem::size_of::<CompositeUniforms>(),
    );
}

/// The reflection has teeth: a drifted member offset, a renamed override or a
/// moved binding is caught.
#[test]
fn reflection_catches_drift() {
    // An extra member shifts every later offset.
    let drifted = incore().replace("    near: f32,\n", "    near: f32,\n    extra: f32,\n");
    let (members, _) = wgsl_struct(&module("drifted", &drifted), "Frame");
    assert_ne!(members, frame_fields());
    // Two members swapped keep the size but not the names.
    let swapped = incore().replace(
        "    ambient: f32,\n    diffuse: f32,",
        "    diffuse: f32,\n    ambient: f32,",
    );
    let (members, _) = wgsl_struct(&module("swapped", &swapped), "Frame");
    assert_ne!(members, frame_fields());
    // A renamed override.
    let renamed = incore()
        .replace("override SHADE", "override SHADING")
        .replace("(SHADE)", "(SHADING)");
    let m = module("renamed", &renamed);
    assert!(
        !m.overrides
            .iter()
            .any(|(_, o)| o.name.as_deref() == Some("SHADE"))
    );
    // A moved binding.
    let moved = incore().replace("@group(2) @binding(3)", "@group(2) @binding(7)");
    assert_ne!(
        wgsl_bindings(&module("moved", &moved)),
        kernel_bindings(&volume_layout_entries(1))
    );
    // The usage counters made read-only.
    let ro = ooc().replace(
        "var<storage, read_write> usage: array<atomic<u32>>",
        "var<storage, read> usage: array<u32>",
    );
    let ro = ro
        .replace("atomicAdd(&usage[2u * slot], 1u);", "let _u = usage[slot];")
        .replace(
            "atomicAdd(&usage[2u * slot + 1u], q);",
            "let _w = usage[slot];",
        );
    assert_ne!(
        wgsl_bindings(&module("read-only usage", &ro)),
        kernel_bindings(&crate::group2::ooc_layout_entries())
    );
    // A renamed prediction override, a moved prediction binding.
    // (Every use renamed too, so that the kernel still parses.)
    let renamed = incore().replace("GUARD", "FIRST_HIT_GUARD");
    let m = module("renamed guard", &renamed);
    assert!(
        !m.overrides
            .iter()
            .any(|(_, o)| o.name.as_deref() == Some("GUARD"))
    );
    let moved = incore().replace("@group(0) @binding(6)", "@group(0) @binding(7)");
    assert_ne!(
        wgsl_bindings(&module("moved", &moved)),
        kernel_bindings(&volume_layout_entries(1))
    );
    // A changed flag bit.
    let flag = incore().replace("FLAG_REVERSED_Z: u32 = 4u", "FLAG_REVERSED_Z: u32 = 8u");
    assert_ne!(
        const_u32(&module("flag", &flag), "FLAG_REVERSED_Z"),
        FrameFlags::REVERSED_Z.0
    );
}

/// Every `.wgsl` file of the crate is part of a validated shader.
#[test]
fn every_shader_file_is_covered() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let known = [
        "common.wgsl",
        "modes.wgsl",
        "incore.wgsl",
        "ooc.wgsl",
        "feedback.wgsl",
        "occlusion.wgsl",
        "composite.wgsl",
        "predict.wgsl",
        "incore_predict.wgsl",
        "ooc_predict.wgsl",
        "reproject.wgsl",
        "gradients.wgsl",
        "slice.wgsl",
        "slice_incore.wgsl",
        "slice_ooc.wgsl",
        "overlay.wgsl",
        "channels.wgsl",
        "channel_class.wgsl",
        "channel_slice.wgsl",
        "ooc_volume.wgsl",
        "ooc_channels.wgsl",
    ];
    for entry in std::fs::read_dir(dir).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        if name.ends_with(".wgsl") {
            assert!(
                known.contains(&name.as_str()),
                "{name} is not validated by any test"
            );
        }
    }
}
