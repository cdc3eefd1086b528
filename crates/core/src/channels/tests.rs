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

/// A u16 source of `dims` whose every sample is `fill` (uniform nodes where
/// `uniform`), counting its brick reads.
struct Flat {
    layout: crate::OctreeLayout,
    fill: u16,
    uniform: bool,
    reads: std::sync::atomic::AtomicUsize,
}

impl Flat {
    fn new(dims: [u32; 3], fill: u16, range: [f32; 2], uniform: bool) -> Flat {
        let desc = VolumeDesc {
            dims,
            dtype: DType::U16,
            spacing: [1.0; 3],
            value_range: range,
            kind: VolumeKind::Intensity,
        };
        Flat {
            layout: crate::OctreeLayout::new(desc, 4, 1),
            fill,
            uniform,
            reads: Default::default(),
        }
    }
}

impl crate::BrickSource for Flat {
    fn layout(&self) -> &crate::OctreeLayout {
        &self.layout
    }
    fn node(&self, key: crate::NodeKey) -> Result<crate::NodeInfo, crate::BrickError> {
        let v = self.fill as f32;
        Ok(crate::NodeInfo {
            kind: if !self.layout.in_volume(key) {
                crate::NodeKind::Empty
            } else if self.uniform {
                crate::NodeKind::Uniform(v)
            } else {
                crate::NodeKind::Data
            },
            min: v,
            max: v,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        })
    }
    fn read_brick(&self, _key: crate::NodeKey, out: &mut [u8]) -> Result<(), crate::BrickError> {
        self.reads
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        for c in out.chunks_exact_mut(2) {
            c.copy_from_slice(&self.fill.to_le_bytes());
        }
        Ok(())
    }
}

/// A channel source interleaves its channels' bricks (channel fastest),
/// reads each channel once per brick (one call or a batch), keeps each
/// channel's range in the node's metadata, and is empty only where every
/// channel is.
#[test]
fn a_channel_source_interleaves_its_channels() {
    use crate::BrickSource;
    let parts: Vec<std::sync::Arc<Flat>> = vec![
        std::sync::Arc::new(Flat::new([10, 9, 8], 7, [0.0, 100.0], false)),
        std::sync::Arc::new(Flat::new([10, 9, 8], 300, [0.0, 1000.0], true)),
        std::sync::Arc::new(Flat::new([10, 9, 8], 2, [0.0, 10.0], false)),
    ];
    let dyns = parts
        .iter()
        .map(|p| p.clone() as std::sync::Arc<dyn crate::BrickSource>)
        .collect();
    let src = ChannelSource::new(dyns).unwrap();
    let l = src.layout();
    assert!(l.is_channel_volume());
    assert_eq!(l.channels(), 3);
    assert_eq!(
        l.channel_ranges(),
        &[[0.0, 100.0], [0.0, 1000.0], [0.0, 10.0]]
    );
    assert_eq!(l.brick_bytes(), 6usize.pow(3) * 2 * 3);
    let key = crate::NodeKey::new(l.levels - 1, 1, 0, 1);
    let mut b = vec![0u8; l.brick_bytes()];
    src.read_brick(key, &mut b).unwrap();
    let s: Vec<u16> = b
        .chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    assert!(s.chunks_exact(3).all(|v| v == [7, 300, 2]), "{:?}", &s[..9]);
    assert!(
        parts
            .iter()
            .all(|p| p.reads.load(std::sync::atomic::Ordering::Relaxed) == 1)
    );
    // A batch reads each channel once per brick too, into the same bytes.
    let mut b2 = vec![0u8; l.brick_bytes()];
    let mut b3 = vec![0u8; l.brick_bytes()];
    let r = src.read_bricks(
        &[key, crate::NodeKey::new(0, 0, 0, 0)],
        &mut [&mut b2, &mut b3],
        &crate::CancelToken::new(),
    );
    assert!(r.iter().all(Result::is_ok));
    assert_eq!(b2, b);
    assert!(
        parts
            .iter()
            .all(|p| p.reads.load(std::sync::atomic::Ordering::Relaxed) == 3)
    );
    // Metadata: a uniform channel is a range of one value; data either way.
    let i = src.node(key).unwrap();
    assert_eq!(i.kind, crate::NodeKind::Data);
    assert_eq!(&i.channels[..3], &[[7.0, 7.0], [300.0, 300.0], [2.0, 2.0]]);
    assert_eq!((i.min, i.max), (7.0, 7.0));
    assert_eq!(i.error, None);
    assert_eq!(src.nodes(&[key])[0].as_ref().unwrap(), &i);
    // Outside the volume every channel is empty: so is the node.
    let out = crate::NodeKey::new(l.levels - 1, 3, 3, 3);
    assert_eq!(src.node(out).unwrap().kind, crate::NodeKind::Empty);
    // A wrong buffer is a typed error.
    assert!(matches!(
        src.read_brick(key, &mut [0u8; 3]),
        Err(crate::BrickError::BufferSize { .. })
    ));
}

#[test]
fn channel_sources_share_one_octree() {
    let a = std::sync::Arc::new(Flat::new([10, 9, 8], 1, [0.0, 1.0], false));
    let b = std::sync::Arc::new(Flat::new([10, 9, 9], 1, [0.0, 1.0], false));
    let e = ChannelSource::new(vec![a.clone(), b]).unwrap_err();
    assert!(
        matches!(
            e,
            ChannelError::Mismatch {
                channel: 1,
                what: "octree",
                ..
            }
        ),
        "{e}"
    );
    let five: Vec<std::sync::Arc<dyn crate::BrickSource>> = (0..5)
        .map(|_| a.clone() as std::sync::Arc<dyn crate::BrickSource>)
        .collect();
    assert!(matches!(
        ChannelSource::new(five),
        Err(ChannelError::Count { count: 5, .. })
    ));
    // A channel source is not a channel of another.
    let inner = std::sync::Arc::new(ChannelSource::new(vec![a.clone(), a.clone()]).unwrap());
    assert!(matches!(
        ChannelSource::new(vec![a, inner]),
        Err(ChannelError::Mismatch {
            what: "channels",
            ..
        })
    ));
}

proptest! {
    /// A node is visible when some visible channel is, each by the rule of
    /// one channel over its own value range: DVR not transparent, iso at or
    /// below the top of the range, MIP always.
    #[test]
    fn a_node_is_visible_when_a_visible_channel_is(
        ranges in proptest::collection::vec(proptest::array::uniform2(0.0f32..100.0), 1..=4),
        vis in proptest::array::uniform4(any::<bool>()),
        edges in proptest::array::uniform4(0.0f32..1.0),
        mode in 0usize..3,
    ) {
        let n = ranges.len();
        let value_ranges: Vec<[f32; 2]> = (0..n).map(|c| [0.0, 50.0 + 10.0 * c as f32]).collect();
        let styles: Vec<ChannelStyle> = (0..n)
            .map(|c| {
                let s = ChannelStyle::window([1.0, 0.5, 0.2], [edges[c], (edges[c] + 0.1).min(1.0)], 0.5)
                    .with_isovalue(edges[c]);
                if vis[c] { s } else { s.visible(false) }
            })
            .collect();
        let mode = [crate::RenderMode::Dvr, crate::RenderMode::Iso { value: 0.5, color: [1.0; 3] }, crate::RenderMode::Mip][mode];
        let want = (0..n).filter(|&c| vis[c]).any(|c| {
            let norm = |v: f32| v / value_ranges[c][1];
            let (lo, hi) = (norm(ranges[c][0].min(ranges[c][1])), norm(ranges[c][0].max(ranges[c][1])));
            match mode {
                crate::RenderMode::Dvr => !styles[c].tf.is_transparent(lo, hi),
                crate::RenderMode::Iso { .. } => styles[c].isovalue <= hi,
                _ => true,
            }
        });
        prop_assert_eq!(node_visible(&ranges, &value_ranges, &styles, mode), want);
    }
}
