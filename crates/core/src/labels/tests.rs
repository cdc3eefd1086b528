use super::*;
use proptest::prelude::*;

#[test]
fn mode_breaks_ties_to_the_smallest() {
    assert_eq!(mode_of(&mut [3u32, 1, 3, 1, 2, 2, 9, 9]), 1);
    assert_eq!(mode_of(&mut [7u32, 0, 9, 9, 7, 7, 0, 9]), 7);
    assert_eq!(mode_of(&mut [5u8; 8]), 5);
    assert_eq!(mode_of(&mut [4u16, 8, 8, 8, 4, 4, 4, 2]), 4);
}

#[test]
fn the_average_of_neighbouring_labels_is_not_a_label_but_the_mode_is() {
    // The case: averaging {0, 7, 9} invents labels; the mode does not.
    let v = [0u32, 7, 9, 9, 7, 0, 9, 7];
    let mean = v.iter().sum::<u32>() as f32 / 8.0;
    assert!(!v.contains(&(mean.round() as u32)));
    let m = mode_of(&mut v.clone());
    assert!(v.contains(&m));
}

fn random_labels(dims: [u32; 3], ids: &[u32], seed: u64) -> Volume {
    let n = (dims[0] * dims[1] * dims[2]) as usize;
    let mut s = seed | 1;
    let mut data = Vec::with_capacity(n);
    let mut cur = ids[0];
    for _ in 0..n {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        // Runs of one label (segments), switching now and then.
        if s.is_multiple_of(5) {
            cur = ids[(s >> 8) as usize % ids.len()];
        }
        data.push(cur);
    }
    label_volume(dims, [1.0; 3], VolumeData::U32(data)).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Every coarser level holds only labels of the finest, and the share of
    /// changed voxels is a share (and 0 where the data is one label).
    #[test]
    fn mode_pyramid_keeps_labels(
        dims in prop::array::uniform3(1u32..13),
        ids in prop::collection::btree_set(0u32..2000, 1..6),
        seed in any::<u64>(),
    ) {
        let ids: Vec<u32> = ids.into_iter().collect();
        let fine = random_labels(dims, &ids, seed);
        let present: BTreeSet<u32> = labels_present(&fine).into_iter().collect();
        let mut level = fine.clone();
        for l in 1..4u32 {
            level = downsample_mode(&level);
            for id in labels_present(&level) {
                prop_assert!(present.contains(&id), "level {l} invents label {id}");
            }
            let share = changed_share(&fine, &level, l);
            prop_assert!((0.0..=1.0).contains(&share));
            if present.len() == 1 {
                prop_assert_eq!(share, 0.0);
            }
        }
    }

    /// The label table is exact: label i's normalized value looks up entry i
    /// alone, whatever the neighbours' colours.
    #[test]
    fn table_lookup_is_exact(id in 0u32..LABEL_TABLE_ENTRIES as u32, hide in any::<bool>()) {
        let mut t = LabelTable::default();
        if hide {
            t.set_visible(id, false);
        }
        let tf = t.to_transfer_function();
        let [lo, hi] = label_value_range();
        let v = (id as f64 - lo as f64) / (hi as f64 - lo as f64);
        let got = tf.lookup(v);
        let want = t.rgba(id);
        for c in 0..4 {
            prop_assert!((got[c] - want[c] as f64).abs() < 1e-6);
        }
        if hide {
            prop_assert_eq!(got[3], 0.0);
        }
    }
}

#[test]
fn changed_share_counts_voxels() {
    // 2x1x1 volume {1, 2}: the mode is 1, one voxel of two changes.
    let fine = label_volume([2, 1, 1], [1.0; 3], VolumeData::U8(vec![1, 2])).unwrap();
    let coarse = downsample_mode(&fine);
    assert_eq!(coarse.data().label(0), 1);
    assert_eq!(changed_share(&fine, &coarse, 1), 0.5);
}

#[test]
fn label_volumes_check_type_and_ids() {
    let bad = label_volume([1, 1, 1], [1.0; 3], VolumeData::F32(vec![1.0]));
    assert!(matches!(
        bad,
        Err(LabelError::Volume(VolumeError::LabelType(DType::F32)))
    ));
    let big = label_volume([2, 1, 1], [1.0; 3], VolumeData::U32(vec![0, 70_000]));
    assert!(matches!(
        big,
        Err(LabelError::IdTooLarge { id: 70_000, .. })
    ));
    let vol = Volume::new(
        VolumeDesc {
            dims: [3, 1, 1],
            dtype: DType::U32,
            spacing: [1.0; 3],
            value_range: [0.0, 1.0],
            kind: VolumeKind::Intensity,
        },
        VolumeData::U32(vec![70_000, 0, 5]),
    )
    .unwrap();
    let (dense, ids) = relabel_dense(&vol).unwrap();
    assert_eq!(ids, vec![0, 5, 70_000]);
    assert_eq!(dense.data(), &VolumeData::U16(vec![2, 0, 1]));
    assert!(dense.desc().kind.is_labels());
}

#[test]
fn table_selection_hover_and_files() {
    let mut t = LabelTable::default();
    assert_eq!(t.rgba(0)[3], 0.0, "background hidden");
    assert_eq!(t.rgba(3)[3], 0.5);
    assert_ne!(hashed_color(3), hashed_color(4));
    t.selected.insert(3);
    assert_eq!(t.rgba(3)[3], 0.5);
    assert_eq!(t.rgba(4)[3], 0.0, "the rest dimmed to unselected_opacity");
    t.hover = Some(4);
    assert_eq!(t.rgba(4)[3], 0.5);
    t.selected.clear();
    t.show_only(&[5]);
    assert_eq!(t.rgba(5)[3], 0.5);
    assert_eq!(t.rgba(3)[3], 0.0);
    assert_eq!(t.rgba(1234)[3], 0.0, "absent ids hidden too");
    t.show_all();
    assert_eq!(t.rgba(3)[3], 0.5);
    let back = LabelTable::from_file_bytes(t.to_json().as_bytes()).unwrap();
    assert_eq!(back, t);
    let mut lut = vec![0u8; 768];
    lut[7] = 255;
    lut[256 + 7] = 128;
    let t = LabelTable::from_file_bytes(&lut).unwrap();
    let c = t.rgba(7);
    assert_eq!(c[0], 1.0);
    assert!((c[1] - 128.0 / 255.0).abs() < 1e-6);
    assert_eq!(c[2], 0.0);
    assert!(LabelTable::from_file_bytes(&[0xff; 10]).is_err());
}

/// A smooth boundary's normal: the gradient of the heaviest label's
/// filtered indicator, across the boundary, zero inside one label.
#[test]
fn smooth_label_gradients_cross_the_boundary() {
    let ids: Vec<u8> = (0..64).map(|i| if i % 4 < 2 { 1 } else { 2 }).collect();
    let v = label_volume([4, 4, 4], [1.0; 3], VolumeData::U8(ids)).unwrap();
    let (l, g) = smooth_label_gradient(&v, [1.3, 1.5, 1.5]);
    assert_eq!(l, 1);
    assert!(
        (g[0] + 1.0).abs() < 1e-12 && g[1].abs() < 1e-12 && g[2].abs() < 1e-12,
        "{g:?}"
    );
    let (l, g) = smooth_label_gradient(&v, [1.8, 1.5, 1.5]);
    assert_eq!(l, 2);
    assert!((g[0] - 1.0).abs() < 1e-12, "{g:?}");
    assert_eq!(smooth_label_gradient(&v, [0.5, 1.0, 2.0]), (1, [0.0; 3]));
    assert_eq!(smooth_label_at(&v, [1.3, 1.5, 1.5]), 1);
}
