//! The multi-channel kernels (in core and out of core): their entry points,
//! overrides, group 2 and uniforms against the Rust side, and every
//! permutation a pipeline can have.

use super::permutations::{octree_both, specialise};
use super::*;

/// The multi-channel kernel: one entry point, the shared overrides and
/// `CHANNELS`, its group 2 and `ChannelParams` against the Rust side, and
/// the opacity limit of the mixture against brickray-core's.
#[test]
fn channels_kernel_matches_the_rust_side() {
    use crate::backend::channels::ChannelParams;
    let m = module("channels", &channels());
    let names: Vec<&str> = m.entry_points.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(
        names,
        [crate::kernels::ENTRY_RAYCAST, crate::kernels::ENTRY_SLICE]
    );
    for (wgsl, mode) in [
        ("SLAB_MAX", crate::slice::SLAB_MAX),
        ("SLAB_MEAN", crate::slice::SLAB_MEAN),
    ] {
        assert_eq!(const_u32(&m, wgsl), mode, "channels: {wgsl}");
    }
    check_kernel_common(
        "channels",
        &m,
        &crate::backend::channels::layout_entries(),
        &["CHANNELS"],
    );
    check_struct(
        &m,
        "ChannelParams",
        rust_fields!(
            ChannelParams,
            [
                dims,
                channels,
                cells,
                cell_size,
                scale,
                offset,
                tf_count,
                tf_offset,
                table_rows,
                table_width,
                pad0,
                pad1
            ]
        ),
        std::mem::size_of::<ChannelParams>(),
    );
    let (_, c) = m
        .constants
        .iter()
        .find(|(_, c)| c.name.as_deref() == Some("OPAQUE_ALPHA"))
        .expect("OPAQUE_ALPHA");
    let v = match m.global_expressions[c.init] {
        naga::Expression::Literal(naga::Literal::F32(v)) => v,
        ref e => panic!("OPAQUE_ALPHA is not an f32 literal: {e:?}"),
    };
    assert_eq!(v as f64, brickray_core::channels::OPAQUE_ALPHA);
    assert_eq!(
        const_u32(&m, "CLASS_HEADER") as usize,
        crate::backend::channels::CLASS_HEADER
    );
}

/// Every channel count (1-4) with every mode and combination of ERT, ESS
/// and shading, and with a label map over the channels (colour and mask,
/// shaded, smooth boundaries), validates as the multi-channel kernel's
/// pipelines specialise it (pre-integration, prediction and labels off, as
/// `Variant::channels` has them).
#[test]
fn every_channel_permutation_validates() {
    let src = channels();
    let mut combos = Vec::new();
    for (_, mode) in KernelMode::ALL {
        for bits in 0..8u32 {
            combos.push((mode, bits, 0));
        }
        // A label map over the channels (colour, mask), with ERT and ESS,
        // shaded, and with smooth label boundaries.
        for overlay in [1, 2] {
            for bits in [0b011, 0b111, 0b011 | 1 << 9] {
                combos.push((mode, bits, overlay));
            }
        }
    }
    for n in 1..=4u32 {
        for &(mode, bits, overlay) in &combos {
            let s = specialise("channels", &src, mode, bits, overlay).replace(
                "override CHANNELS: u32 = 1u;",
                &format!("const CHANNELS: u32 = {n}u;"),
            );
            assert!(!s.contains("override "), "channels: an override left");
            module(
                &format!("channels {n} {mode:?} {bits:010b} overlay {overlay}"),
                &s,
            );
        }
    }
}

/// The multi-channel out-of-core kernel: its ray caster and slice view,
/// the shared overrides and `CHANNELS`, its group 2 (the out-of-core
/// bindings and the classification's) and its uniforms against the Rust
/// side.
#[test]
fn ooc_channels_kernel_matches_the_rust_side() {
    use crate::backend::ooc_channels::OocChannelParams;
    let m = module("ooc channels", &ooc_channels());
    let names: Vec<&str> = m.entry_points.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(
        names,
        [crate::kernels::ENTRY_RAYCAST, crate::kernels::ENTRY_SLICE]
    );
    check_kernel_common(
        "ooc channels",
        &m,
        &crate::backend::ooc_channels::layout_entries(),
        &["CHANNELS", crate::kernels::OCTREE_OVERRIDE],
    );
    check_struct(
        &m,
        "OocChannelParams",
        rust_fields!(
            OocChannelParams,
            [
                scale,
                offset,
                tf_count,
                tf_offset,
                prefix_offset,
                table_rows,
                table_width,
                pad0,
                pad1
            ]
        ),
        std::mem::size_of::<OocChannelParams>(),
    );
    check_ooc_params(&m);
    assert_eq!(
        const_u32(&m, "CLASS_HEADER") as usize,
        crate::backend::channels::CLASS_HEADER
    );
}

/// Every channel count (1-4) with every mode and combination of ERT, ESS,
/// shading and the visible weights, and with a label map over the channels
/// (colour and mask), validates as the out-of-core multi-channel pipelines
/// specialise it.
#[test]
fn every_ooc_channel_permutation_validates() {
    let src = ooc_channels();
    let weights = 1 << 7;
    let mut combos = Vec::new();
    for (_, mode) in KernelMode::ALL {
        for bits in 0..8u32 {
            combos.push((mode, bits, 0));
            combos.push((mode, bits | weights, 0));
        }
        for overlay in [1, 2] {
            combos.push((mode, 0b111, overlay));
        }
    }
    for n in 1..=4u32 {
        for &(mode, bits, overlay) in &combos {
            let s = specialise("ooc channels", &src, mode, bits, overlay).replace(
                "override CHANNELS: u32 = 1u;",
                &format!("const CHANNELS: u32 = {n}u;"),
            );
            for s in octree_both(&s) {
                assert!(!s.contains("override "), "ooc channels: an override left");
                module(
                    &format!("ooc channels {n} {mode:?} {bits:010b} overlay {overlay}"),
                    &s,
                );
            }
        }
    }
}
