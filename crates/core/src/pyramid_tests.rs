use super::*;
use crate::volume::DType;
use proptest::prelude::*;

fn desc(dims: [u32; 3], spacing: [f32; 3]) -> VolumeDesc {
    VolumeDesc {
        dims,
        dtype: DType::U8,
        spacing,
        value_range: [0.0, 255.0],
        kind: Default::default(),
    }
}

/// The node holding finest voxel `v` at `level`, by direct arithmetic.
fn node_of(layout: &OctreeLayout, v: [u64; 3], level: u8) -> NodeKey {
    let f = layout.voxel_factor(level);
    let b = layout.brick as u64;
    let p: [u32; 3] = std::array::from_fn(|a| (v[a] / (f[a] as u64 * b)) as u32);
    NodeKey::new(level, p[0], p[1], p[2])
}

#[test]
fn head_ct_at_thick_slices_halves_x_and_y_first() {
    // 256 x 256 x 36 at 0.957 x 0.957 x 4.5 mm: x and y are halved twice
    // (0.96 -> 1.9 -> 3.8 mm) before the voxel is near-isotropic.
    let masks = anisotropic_split_masks([256, 256, 36], [0.957, 0.957, 4.5], 32);
    assert_eq!(masks, vec![ALL_AXES, 0b011, 0b011]);
    let l = OctreeLayout::anisotropic(desc([256, 256, 36], [0.957, 0.957, 4.5]), 32, 2);
    assert_eq!(l.levels, 4);
    assert_eq!(l.cube_voxels_axes(), [256, 256, 64]);
    assert_eq!(l.level_dims(0), [32, 32, 18]);
    assert_eq!(l.level_dims(1), [64, 64, 36]);
    assert_eq!(l.level_dims(2), [128, 128, 36]);
    assert_eq!(l.child_count(0), 8);
    assert_eq!(l.child_count(1), 4);
    assert_eq!(l.children(NodeKey::new(3, 0, 0, 0)).len(), 0);
    assert_eq!(l.voxel_factor(1), [4.0, 4.0, 1.0]);
}

#[test]
fn bad_masks_are_typed_errors() {
    let d = desc([256, 256, 36], [1.0, 1.0, 4.5]);
    assert!(matches!(
        OctreeLayout::with_split_masks(d.clone(), 32, 2, &[7, 0, 3]),
        Err(LayoutError::BadMask { level: 1, mask: 0 })
    ));
    assert!(matches!(
        OctreeLayout::with_split_masks(d.clone(), 32, 2, &[7, 8, 3]),
        Err(LayoutError::BadMask { .. })
    ));
    assert!(matches!(
        OctreeLayout::with_split_masks(d.clone(), 32, 2, &[3, 3]),
        Err(LayoutError::Coverage { .. })
    ));
    // One level more than needed.
    assert!(matches!(
        OctreeLayout::with_split_masks(d.clone(), 32, 2, &[7, 7, 3, 3]),
        Err(LayoutError::Coverage { .. })
    ));
    assert!(matches!(
        OctreeLayout::with_split_masks(d, 32, 2, &[7; 40]),
        Err(LayoutError::TooManyLevels { .. })
    ));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Near-isotropic voxels give exactly the isotropic octree, and the mask-aware
    /// key operations equal `NodeKey`'s there.
    #[test]
    fn isotropic_layout_is_unchanged(
        dims in prop::array::uniform3(1u32..300),
        s in 0.1f32..10.0,
        jitter in prop::array::uniform3(1.0f32..1.4),
        brick in 1u32..40,
        x in 0u32..64, y in 0u32..64, z in 0u32..64, i in 0u8..8,
    ) {
        let spacing = [s * jitter[0], s * jitter[1], s * jitter[2]];
        let iso = OctreeLayout::new(desc(dims, spacing), brick, 1);
        let an = OctreeLayout::anisotropic(desc(dims, spacing), brick, 1);
        prop_assert_eq!(&an, &iso);
        prop_assert!(an.is_isotropic());
        let back = OctreeLayout::with_split_masks(desc(dims, spacing), brick, 1, &iso.split_masks()).unwrap();
        prop_assert_eq!(&back, &iso);
        for level in 0..iso.levels {
            let k = NodeKey::new(level, x % (1 << level), y % (1 << level), z % (1 << level));
            prop_assert_eq!(iso.parent(k), k.parent());
            prop_assert_eq!(iso.child_index(k), if level == 0 { 0 } else { k.child_index() });
            let (o, side) = k.unit_box();
            prop_assert_eq!(iso.unit_box(k), (o, [side; 3]));
            if level + 1 < iso.levels {
                prop_assert_eq!(iso.child(k, i), k.child(i));
                prop_assert_eq!(&iso.children(k)[..], &k.children()[..]);
            }
        }
    }

    /// Anisotropic layouts: children tile their parent (child/parent/child_index
    /// agree), the root brick covers the volume, and descending from the root by
    /// child index finds the same node as direct arithmetic for every sampled voxel.
    #[test]
    fn anisotropic_nodes_match_brute_force(
        dims in prop::array::uniform3(1u32..400),
        spacing in prop::array::uniform3(0.1f32..20.0),
        brick in 2u32..40,
        voxels in prop::collection::vec(prop::array::uniform3(0.0f64..1.0), 1..8),
    ) {
        let l = OctreeLayout::anisotropic(desc(dims, spacing), brick, 1);
        let masks = l.split_masks();
        prop_assert_eq!(masks.len() + 1, l.levels as usize);
        let back = OctreeLayout::with_split_masks(desc(dims, spacing), brick, 1, &masks).unwrap();
        prop_assert_eq!(&back, &l);
        prop_assert_eq!(l.level_dims(l.levels - 1), dims);
        prop_assert!(l.level_dims(0).iter().all(|d| *d <= brick));
        let cube = l.cube_voxels_axes();
        prop_assert!((0..3).all(|a| cube[a] >= dims[a] as u64));
        // Finest voxels stay within sqrt(2) of isotropic once x/y/z halving starts.
        for u in voxels {
            let v: [u64; 3] = std::array::from_fn(|a| ((u[a] * dims[a] as f64) as u64).min(dims[a] as u64 - 1));
            let mut k = NodeKey::ROOT;
            prop_assert_eq!(node_of(&l, v, 0), k);
            for level in 1..l.levels {
                let want = node_of(&l, v, level);
                prop_assert!(l.in_volume(want));
                let ch = l.children(k);
                prop_assert_eq!(ch.len() as u32, l.child_count(level - 1));
                let hits: Vec<_> = ch.iter().filter(|c| **c == want).collect();
                prop_assert_eq!(hits.len(), 1);
                prop_assert_eq!(l.parent(want), Some(k));
                let ci = l.child_index(want);
                prop_assert_eq!(l.child(k, ci), want);
                // The child's unit box lies in the parent's, and contains the voxel.
                let (po, ps) = l.unit_box(k);
                let (co, cs) = l.unit_box(want);
                for a in 0..3 {
                    prop_assert!(co[a] >= po[a] && co[a] + cs[a] <= po[a] + ps[a] + 1e-12);
                    let t = (v[a] as f64 + 0.5) / cube[a] as f64;
                    prop_assert!(co[a] <= t && t <= co[a] + cs[a]);
                }
                k = want;
            }
        }
    }
}
