use super::*;
use crate::volume::{VolumeData, VolumeKind};
use proptest::prelude::*;

fn vol(dims: [u32; 3], dtype: DType, spacing: [f32; 3], kind: VolumeKind) -> Volume {
    let n = (dims[0] * dims[1] * dims[2]) as usize;
    let data = match dtype {
        DType::U8 => VolumeData::U8(vec![1; n]),
        DType::U16 => VolumeData::U16(vec![1; n]),
        _ => VolumeData::F32(vec![1.0; n]),
    };
    let desc = VolumeDesc {
        dims,
        dtype,
        spacing,
        value_range: [0.0, 255.0],
        kind,
    };
    Volume::new(desc, data).unwrap()
}

#[test]
fn a_channel_volume_is_one_grid_of_one_dtype() {
    let a = vol([4, 5, 6], DType::U8, [1.0; 3], VolumeKind::Intensity);
    let cv = ChannelVolume::new(vec![a.clone(), a.clone(), a.clone()]).unwrap();
    assert_eq!((cv.len(), cv.dims(), cv.dtype()), (3, [4, 5, 6], DType::U8));
    assert_eq!(cv.byte_len(), 3 * 120);
    assert_eq!(
        ChannelVolume::new(vec![]),
        Err(ChannelError::Count { count: 0, max: 4 })
    );
    assert!(matches!(
        ChannelVolume::new(vec![a.clone(); 5]),
        Err(ChannelError::Count { count: 5, .. })
    ));
    let cases = [
        (
            vol([4, 5, 7], DType::U8, [1.0; 3], VolumeKind::Intensity),
            "dims",
        ),
        (
            vol([4, 5, 6], DType::U16, [1.0; 3], VolumeKind::Intensity),
            "dtype",
        ),
        (
            vol([4, 5, 6], DType::U8, [1.0, 1.0, 2.0], VolumeKind::Intensity),
            "spacing",
        ),
    ];
    for (other, what) in cases {
        match ChannelVolume::new(vec![a.clone(), other]) {
            Err(ChannelError::Mismatch {
                channel: 1,
                what: w,
                ..
            }) => assert_eq!(w, what),
            r => panic!("{what}: {r:?}"),
        }
    }
    let labels = vol([4, 5, 6], DType::U8, [1.0; 3], VolumeKind::Labels);
    assert_eq!(
        ChannelVolume::new(vec![a, labels]),
        Err(ChannelError::Labels { channel: 1 })
    );
}

#[test]
fn styles_are_checked_against_the_channels() {
    let s = ChannelStyle::window([1.0, 0.0, 0.0], [0.2, 0.6], 0.5);
    assert_eq!(validate_styles(&[s.clone(), s.clone()], 2), Ok(()));
    assert_eq!(
        validate_styles(std::slice::from_ref(&s), 2),
        Err(ChannelError::StyleCount {
            styles: 1,
            channels: 2
        })
    );
    assert_eq!(
        validate_styles(&[s.with_isovalue(f32::NAN)], 1),
        Err(ChannelError::NotFinite {
            channel: 0,
            what: "the isovalue"
        })
    );
}

/// A window style is transparent up to its low end, reaches its opacity at
/// its high end and keeps it; its colour is constant and its isovalue is the
/// window's middle.
#[test]
fn a_window_is_a_ramp_in_one_colour() {
    let s = ChannelStyle::window([0.0, 1.0, 0.5], [0.25, 0.75], 0.8);
    for (v, a) in [(0.0, 0.0), (0.25, 0.0), (0.5, 0.4), (0.75, 0.8), (1.0, 0.8)] {
        let c = s.tf.lookup(v);
        assert!((c[3] - a).abs() < 2e-3, "{v}: {c:?}");
        assert!(
            (c[1] - 1.0).abs() < 1e-6 && (c[2] - 0.5).abs() < 1e-6,
            "{v}: {c:?}"
        );
    }
    assert_eq!(s.isovalue, 0.5);
    assert_eq!(s.iso_color(), [0.0, 1.0, 0.5]);
    // A window of zero width is a step, not a division by zero.
    let step = ChannelStyle::window([1.0; 3], [0.5, 0.5], 1.0);
    assert_eq!(step.tf.lookup(0.4)[3], 0.0);
    assert!(step.tf.lookup(0.6)[3] > 0.99);
}

fn sample() -> impl Strategy<Value = ([f64; 3], f64)> {
    (proptest::array::uniform3(0.0f64..=1.0), 0.0f64..=1.0)
}

proptest! {
    /// One channel is its own sample, premultiplied.
    #[test]
    fn one_channel_is_its_own_sample((c, a) in sample()) {
        let m = mix(&[(c, a)]);
        prop_assert!((m[3] - a).abs() < 1e-12);
        for k in 0..3 {
            prop_assert!((m[k] - a * c[k]).abs() < 1e-9, "{m:?}");
        }
    }

    /// The mixture's opacity is one minus the product of transmittances,
    /// its colour a weighted mean of the channels' (so never above its
    /// opacity), the order of the channels does not matter, and a channel of
    /// zero opacity (a hidden one) is absent.
    #[test]
    fn the_mixture_is_an_absorber_mixture(s in proptest::collection::vec(sample(), 1..=4), k in 0usize..4) {
        let m = mix(&s);
        let keep: f64 = s.iter().map(|x| 1.0 - x.1).product();
        prop_assert!((m[3] - (1.0 - keep)).abs() < 1e-12);
        for q in 0..3 {
            let lo = s.iter().filter(|x| x.1 > 0.0).map(|x| x.0[q]).fold(f64::INFINITY, f64::min);
            let hi = s.iter().filter(|x| x.1 > 0.0).map(|x| x.0[q]).fold(f64::NEG_INFINITY, f64::max);
            if m[3] > 0.0 {
                let straight = m[q] / m[3];
                prop_assert!(straight >= lo - 1e-9 && straight <= hi + 1e-9, "{m:?} {s:?}");
            }
        }
        let mut r = s.clone();
        r.reverse();
        let mr = mix(&r);
        for q in 0..4 {
            prop_assert!((m[q] - mr[q]).abs() < 1e-12);
        }
        let k = k % s.len();
        let mut hidden = s.clone();
        hidden[k].1 = 0.0;
        let mut without = s.clone();
        without.remove(k);
        let (a, b) = (mix(&hidden), mix(&without));
        for q in 0..4 {
            prop_assert!((a[q] - b[q]).abs() < 1e-12);
        }
    }

    /// A cell is empty when it is in every visible channel; hidden channels
    /// never keep it.
    #[test]
    fn cells_are_empty_in_every_visible_channel(
        v in proptest::collection::vec(proptest::array::uniform2(0.0f32..1.0), 8..=8),
        vis in proptest::array::uniform2(any::<bool>()),
    ) {
        let (a, b) = v.split_at(4);
        let empty = cells_empty(&[a, b], &vis, |c, r| r[1] < 0.5 + 0.1 * c as f32);
        for i in 0..4 {
            let ea = !vis[0] || a[i][1] < 0.5;
            let eb = !vis[1] || b[i][1] < 0.6;
            prop_assert_eq!(empty[i], ea && eb);
        }
    }
}

#[test]
fn no_channel_and_opaque_channels_mix_to_finite_samples() {
    assert_eq!(mix(&[]), [0.0; 4]);
    assert_eq!(mix(&[([1.0, 0.0, 0.0], 0.0)]), [0.0; 4]);
    let m = mix(&[([1.0, 0.0, 0.0], 1.0), ([0.0, 1.0, 0.0], 1.0)]);
    assert_eq!(m[3], 1.0);
    assert!(
        (m[0] - 0.5).abs() < 1e-12 && (m[1] - 0.5).abs() < 1e-12,
        "{m:?}"
    );
}

#[test]
fn channels_interleave_into_lanes() {
    assert_eq!((1..=4).map(texel_lanes).collect::<Vec<_>>(), [1, 2, 4, 4]);
    let a = [1u8, 2, 3, 4];
    let b = [5u8, 6, 7, 8];
    let c = [9u8, 10, 11, 12];
    // Two-byte texels: two of each channel.
    assert_eq!(interleave(&[&a, &b], 2, 2), [1, 2, 5, 6, 3, 4, 7, 8]);
    assert_eq!(
        interleave(&[&a, &b, &c], 2, 4),
        [1, 2, 5, 6, 9, 10, 0, 0, 3, 4, 7, 8, 11, 12, 0, 0]
    );
    assert_eq!(interleave(&[&a], 1, 1), a);
}

/// A window style's slice shows its colour times the windowed intensity;
/// channels add and clamp; a TF with no opacity shows nothing.
#[test]
fn slices_add_the_channels_at_full_colour() {
    let s = ChannelStyle::window([0.2, 0.6, 1.0], [0.2, 0.6], 0.4);
    let g = slice_gain(&s.tf);
    assert!((g - 2.5).abs() < 1e-6, "{g}");
    let at = |v: f64| {
        let [r, gr, b, a] = s.tf.lookup(v);
        ([r, gr, b], a, g)
    };
    let c = slice_color(&[at(0.4)]);
    assert!(
        (c[2] - 0.5).abs() < 1e-3 && (c[1] - 0.3).abs() < 1e-3,
        "{c:?}"
    );
    assert_eq!(slice_color(&[at(0.1)]), [0.0; 3]);
    let full = slice_color(&[at(0.9), at(0.9)]);
    assert_eq!(full[2], 1.0);
    assert!(
        (full[1] - 1.0).abs() < 1e-6 && (full[0] - 0.4).abs() < 1e-6,
        "{full:?}"
    );
    assert_eq!(slice_gain(&TransferFunction::ramp(0.5, 0.6, 0.0)), 0.0);
}
