//! The kernels specialised as their pipelines compile them: every
//! permutation of the override constants validates with naga.

use super::*;

/// Every permutation of the override constants that a pipeline can have
/// validates with the switches as constants: naga then checks each specialised
/// kernel as a pipeline compiles it. Every mode with every combination of ERT,
/// ESS and shading; the iso mode with prediction on and every combination of
/// its guard, its sparse skipping, ERT and ESS; DVR pre-integrated with every
/// combination of ERT, ESS and shading; the visible weights (WEIGHTS) with
/// every mode and combination of ERT, ESS and shading, with pre-integration
/// and with prediction; label maps (LABELS) with every mode and combination of
/// ERT and ESS, with the visible weights, with smooth boundaries
/// (SMOOTH_LABELS), shaded with smooth boundaries, and the slice views of
/// both; a label map over the image
/// (OVERLAY colour and mask) with DVR and every combination of ERT, ESS and
/// shading, pre-integrated, with the visible weights and smooth boundaries,
/// and in colour with iso (also predicting) and MIP; DVR with spreads
/// (SPREAD) and shaded DVR reading the per-voxel gradients (GRADIENTS);
/// out of core, each with a fading leaf and without (FADES).
#[test]
fn every_override_permutation_validates() {
    let mut combos = Vec::new();
    for (_, mode) in KernelMode::ALL {
        for bits in 0..8u32 {
            combos.push((mode, bits));
        }
    }
    for bits in 0..16u32 {
        // ERT, ESS from bits 0-1; GUARD, SPARSE_ESS from bits 2-3.
        let b = (bits & 3) | 1 << 3 | (bits >> 2) << 4;
        combos.push((KernelMode::Iso, b));
    }
    for bits in 0..8u32 {
        combos.push((KernelMode::Dvr, bits | 1 << 6));
    }
    // The visible weights with every mode and combination of ERT, ESS and
    // shading, pre-integrated DVR and the predicting iso kernel.
    for (_, mode) in KernelMode::ALL {
        for bits in 0..8u32 {
            combos.push((mode, bits | 1 << 7));
        }
    }
    combos.push((KernelMode::Dvr, 0b111 | 1 << 6 | 1 << 7));
    // Iso predicting with its guard and sparse skipping, ERT and ESS.
    combos.push((KernelMode::Iso, 0b1011_1011));
    // Label maps (never shaded nor pre-integrated): every mode with ERT and
    // ESS, and with the visible weights.
    for (_, mode) in KernelMode::ALL {
        for bits in 0..4u32 {
            combos.push((mode, bits | 1 << 8));
            combos.push((mode, bits | 1 << 7 | 1 << 8));
            combos.push((mode, bits | 1 << 8 | 1 << 9));
            combos.push((mode, bits | 1 << 7 | 1 << 8 | 1 << 9));
            // Shaded by the smooth boundary's gradient.
            combos.push((mode, bits | 1 << 2 | 1 << 8 | 1 << 9));
            combos.push((mode, bits | 1 << 2 | 1 << 7 | 1 << 8 | 1 << 9));
        }
    }
    let mut combos: Vec<(KernelMode, u32, u32)> =
        combos.into_iter().map(|(m, b)| (m, b, 0)).collect();
    for overlay in [1u32, 2] {
        for bits in 0..8u32 {
            combos.push((KernelMode::Dvr, bits, overlay));
        }
        combos.push((KernelMode::Dvr, 0b111 | 1 << 6, overlay));
        combos.push((KernelMode::Dvr, 0b011 | 1 << 7, overlay));
        combos.push((KernelMode::Dvr, 0b011 | 1 << 9, overlay));
    }
    // Colour tints iso surfaces (also predicted) and MIP maxima.
    for bits in 0..8u32 {
        combos.push((KernelMode::Iso, bits, 1));
        combos.push((KernelMode::Mip, bits, 1));
    }
    combos.push((KernelMode::Iso, 0b1011_1011, 1));
    combos.push((KernelMode::Mip, 0b011 | 1 << 7, 1));
    // DVR with spreads (bit 10): every combination of ERT, ESS and
    // shading, with the visible weights, and under an overlay.
    for bits in 0..8u32 {
        combos.push((KernelMode::Dvr, bits | 1 << 10, 0));
        combos.push((KernelMode::Dvr, bits | 1 << 7 | 1 << 10, 0));
    }
    for overlay in [1u32, 2] {
        combos.push((KernelMode::Dvr, 0b111 | 1 << 10, overlay));
    }
    // Shaded DVR reading the per-voxel gradients (bit 11): with every
    // combination of ERT and ESS, pre-integrated, and under an overlay.
    for bits in 0..4u32 {
        combos.push((KernelMode::Dvr, bits | 1 << 2 | 1 << 11, 0));
        combos.push((KernelMode::Dvr, bits | 1 << 2 | 1 << 6 | 1 << 11, 0));
    }
    for overlay in [1u32, 2] {
        combos.push((KernelMode::Dvr, 0b111 | 1 << 11, overlay));
    }
    // Out of core each with and without a fading leaf (FADES, bit 12); the
    // in-core kernel ignores it.
    let fades = 1u32 << switches().iter().position(|s| *s == "FADES").unwrap();
    for (name, src, fading) in [
        ("incore", incore(), &[0][..]),
        ("ooc", ooc(), &[0, fades][..]),
    ] {
        for &(mode, bits, overlay) in &combos {
            for &f in fading {
                let bits = bits | f;
                let s = specialise(name, &src, mode, bits, overlay);
                // Out of core over an octree and over anisotropic splits
                // (OCT_OCTREE in brickray-index's traversal library).
                for s in octree_both(&s) {
                    assert!(!s.contains("override "), "{name}: an override left");
                    module(
                        &format!("{name} {mode:?} {bits:013b} overlay {overlay}"),
                        &s,
                    );
                }
            }
        }
    }
}

/// The boolean switches of [`every_override_permutation_validates`], in
/// bit order: the override constants between `MODE` and `OVERLAY`.
fn switches() -> &'static [&'static str] {
    assert_eq!(
        (OVERRIDES[0], OVERRIDES[OVERRIDES.len() - 1]),
        ("MODE", "OVERLAY")
    );
    &OVERRIDES[1..OVERRIDES.len() - 1]
}

/// `src` with its override constants made constants: `MODE`, `OVERLAY`,
/// and each of [`switches`] on when its bit of `bits` is set.
/// An out-of-core kernel's source with `OCT_OCTREE` set each way (the
/// source alone where it has none: in core).
pub(super) fn octree_both(src: &str) -> Vec<String> {
    let from = format!(
        "override {}: bool = false;",
        crate::kernels::OCTREE_OVERRIDE
    );
    if !src.contains(&from) {
        return vec![src.to_string()];
    }
    [false, true]
        .map(|on| {
            src.replace(
                &from,
                &format!("const {}: bool = {on};", crate::kernels::OCTREE_OVERRIDE),
            )
        })
        .into()
}

pub(super) fn specialise(
    name: &str,
    src: &str,
    mode: KernelMode,
    bits: u32,
    overlay: u32,
) -> String {
    let mut s = src
        .replace(
            "override MODE: u32 = 0u;",
            &format!("const MODE: u32 = {}u;", mode as u32),
        )
        .replace(
            "override OVERLAY: u32 = 0u;",
            &format!("const OVERLAY: u32 = {overlay}u;"),
        );
    for (i, sw) in switches().iter().enumerate() {
        let on = bits >> i & 1 == 1;
        let from = [true, false]
            .map(|d| format!("override {sw}: bool = {d};"))
            .into_iter()
            .find(|f| s.contains(f.as_str()))
            .unwrap_or_else(|| panic!("{name}: no override {sw}"));
        s = s.replace(&from, &format!("const {sw}: bool = {on};"));
    }
    s
}
