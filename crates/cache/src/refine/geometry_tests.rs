use super::*;
use brickray_core::{DType, VolumeDesc};
use glam::{Mat4, Vec3};
use proptest::prelude::*;

fn desc(dims: [u32; 3], spacing: [f32; 3]) -> VolumeDesc {
    VolumeDesc {
        dims,
        dtype: DType::U8,
        spacing,
        value_range: [0.0, 1.0],
        kind: Default::default(),
    }
}

fn ortho(height: f32) -> Camera {
    let mut c = Camera::orbit(Vec3::ZERO, 1000.0, 0.3, 0.2);
    c.projection = Projection::Orthographic { height };
    c
}

/// Before per-axis metrics: the largest finest voxel side times 2^(finest - level).
fn old_voxel(voxel_world: [f64; 3], levels: u8, level: u8) -> f64 {
    let finest = levels - 1;
    voxel_world.iter().fold(0.0f64, |m, v| m.max(*v)) * 2f64.powi((finest - level) as i32)
}

#[test]
fn thick_slice_ct_levels_project_their_coarsened_sides() {
    // 256 x 256 x 36 at 0.957 x 0.957 x 4.5: levels (root first) have voxels
    // 7.66 x 7.66 x 9, 3.83 x 3.83 x 4.5, 1.91 x 1.91 x 4.5, 0.957 x 0.957 x 4.5.
    let l = OctreeLayout::anisotropic(desc([256, 256, 36], [0.957, 0.957, 4.5]), 32, 2);
    let vw = [0.957, 0.957, 4.5];
    let got: Vec<f64> = (0..4).map(|lv| lod_voxel_world(&l, vw, lv)).collect();
    let want = [9.0, 0.957 * 4.0, 0.957 * 2.0, 0.957];
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 1e-12, "{got:?} vs {want:?}");
    }
    // The isotropic octree of the same volume: 4.5 mm at the finest level, so a
    // 1 px tolerance keeps the finest level until 4.5 mm is 1 px.
    let iso = OctreeLayout::new(desc([256, 256, 36], [0.957, 0.957, 4.5]), 32, 2);
    assert_eq!(lod_voxel_world(&iso, vw, 3), 4.5);
    // In a view: orthographic, so voxel_pixels = size * px per world unit.
    let frame = VolumeFrame::new(
        Mat4::from_scale(Vec3::new(256.0 * 0.957, 256.0 * 0.957, 36.0 * 4.5)),
        [256, 256, 36],
    );
    let geo = ViewGeometry::new(&l, &ortho(256.0), 1.0, 256, &frame);
    let px = geo.voxel_pixels(NodeKey::new(3, 0, 0, 0));
    assert!((px - 0.957).abs() < 1e-4, "{px}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The isotropic octree keeps the old metric exactly, whatever the spacing
    /// and the frame (the per-axis world sides), and the node boxes are unchanged.
    #[test]
    fn isotropic_octree_metric_is_unchanged(
        dims in prop::array::uniform3(1u32..2000),
        vw in prop::array::uniform3(1e-3f64..1e3),
        brick in 1u32..64,
        pos in prop::array::uniform3(0u32..1024),
        scale in prop::array::uniform3(0.1f32..10.0),
    ) {
        let l = OctreeLayout::new(desc(dims, [1.0; 3]), brick, 1);
        for level in 0..l.levels {
            prop_assert_eq!(lod_voxel_world(&l, vw, level), old_voxel(vw, l.levels, level));
        }
        let frame = VolumeFrame::new(Mat4::from_scale(Vec3::from_array(scale)), dims);
        let geo = ViewGeometry::new(&l, &ortho(2.0), 1.0, 64, &frame);
        let lv = l.levels - 1;
        let n = 1u32 << lv;
        let key = NodeKey::new(lv, pos[0] % n, pos[1] % n, pos[2] % n);
        let (o, side) = key.unit_box();
        let s = l.volume_scale();
        let (lo, hi) = geo.tex_box(key);
        for a in 0..3 {
            prop_assert_eq!(lo[a], (o[a] / s[a]).min(1.0));
            prop_assert_eq!(hi[a], ((o[a] + side) / s[a]).min(1.0));
        }
    }

    /// Anisotropic pyramids: each level's metric voxel is the largest side
    /// (finest side times the level's factor) among the axes coarser than the
    /// finest data, never smaller than a coarsened side and never growing
    /// towards the finest level; at the finest level it is the side of the
    /// axes the last level split, not the thick axis.
    #[test]
    fn anisotropic_voxels_project_to_what_they_are(
        dims in prop::array::uniform3(1u32..600),
        spacing in prop::array::uniform3(0.05f32..20.0),
        brick in 2u32..40,
    ) {
        let l = OctreeLayout::anisotropic(desc(dims, spacing), brick, 1);
        let vw = spacing.map(|s| s as f64);
        let finest = l.levels - 1;
        let mut prev = f64::INFINITY;
        for level in 0..l.levels {
            let m = lod_voxel_world(&l, vw, level);
            let f = l.voxel_factor(level);
            let sides: [f64; 3] = std::array::from_fn(|a| vw[a] * f[a]);
            prop_assert!(sides.contains(&m));
            prop_assert!(m <= sides.iter().fold(0.0f64, |x, s| x.max(*s)));
            for a in 0..3 {
                if f[a] > 1.0 {
                    prop_assert!(m >= sides[a]);
                }
            }
            prop_assert!(m <= prev);
            prev = m;
            if level == finest && finest > 0 {
                let last = l.split_mask(finest - 1);
                let want = (0..3).filter(|a| last & (1 << a) != 0).fold(0.0f64, |x, a| x.max(vw[a]));
                prop_assert_eq!(m, want);
            }
        }
    }
}

#[test]
fn centre_weight_is_highest_at_the_centre_of_the_image() {
    let d = desc([64; 3], [1.0; 3]);
    let layout = OctreeLayout::new(d, 8, 1);
    let frame = VolumeFrame::centered([64; 3], [1.0; 3]);
    // Looking at the volume's centre from straight ahead, close enough for
    // the volume to fill most of the view.
    let cam = Camera::orbit(Vec3::ZERO, 1.3, 0.0, 0.0);
    let geo = ViewGeometry::new(&layout, &cam, 1.0, 256, &frame);
    // Level 2 (4 nodes an axis): a central node against a corner node.
    let centre = NodeKey {
        level: 2,
        x: 1,
        y: 1,
        z: 1,
    };
    let corner = NodeKey {
        level: 2,
        x: 0,
        y: 0,
        z: 0,
    };
    let (wc, wk) = (geo.centre_weight(centre), geo.centre_weight(corner));
    assert!(wc > wk + 0.1, "{wc} vs {wk}");
    assert!(wc <= 1.0 && wk > 0.0 && wk < 0.7, "{wc} {wk}");
    // The whole volume is centred.
    assert!((geo.centre_weight(NodeKey::ROOT) - 1.0).abs() < 1e-9);
    // The eye inside the volume: of two nodes at either end of the view axis,
    // the one behind the eye weighs exactly 0.5, the one in front is projected.
    let inside = Camera::orbit(Vec3::ZERO, 0.05, 0.0, 0.0);
    let geo = ViewGeometry::new(&layout, &inside, 1.0, 256, &frame);
    let w: Vec<f64> = [0, 3]
        .map(|z| {
            geo.centre_weight(NodeKey {
                level: 2,
                x: 1,
                y: 1,
                z,
            })
        })
        .to_vec();
    assert_eq!(w.iter().filter(|x| **x == 0.5).count(), 1, "{w:?}");
    assert!(w.iter().all(|x| *x > 0.0 && *x <= 1.0), "{w:?}");
}
