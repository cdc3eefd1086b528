//! Multi-channel test volumes: synthetic blobs (the GPU tests', in core and
//! out of core) and the shared confocal nuclei (the tests' and the
//! `channels` bench's; one source, so both draw the same channels).

use brickray_core::channels::{ChannelStyle, ChannelVolume};
use brickray_core::{DType, Volume, VolumeData, VolumeDesc, VolumeKind};
use glam::Vec3;

/// A 40x36x32 u16 channel (spacing 1, 1, 1.2, values 0..60000): a soft
/// blob of `peak` (0..1) at `centre` (fractions of the grid) over a faint
/// spherical shell.
pub fn blob_channel(centre: [f32; 3], peak: f32) -> Volume {
    let d = [40u32, 36, 32];
    let c = Vec3::from_array(centre);
    let mut v = Vec::with_capacity((d[0] * d[1] * d[2]) as usize);
    for z in 0..d[2] {
        for y in 0..d[1] {
            for x in 0..d[0] {
                let p = Vec3::new(x as f32, y as f32, z as f32) / Vec3::new(40.0, 36.0, 32.0);
                let blob = (-(p - c).length_squared() * 40.0).exp() * peak;
                let r = (p - Vec3::splat(0.5)).length();
                let shell = (-((r - 0.44) * 22.0).powi(2)).exp() * 0.15;
                v.push(((blob + shell).min(1.0) * 60000.0) as u16);
            }
        }
    }
    let desc = VolumeDesc {
        dims: d,
        dtype: DType::U16,
        spacing: [1.0, 1.0, 1.2],
        value_range: [0.0, 60000.0],
        kind: VolumeKind::Intensity,
    };
    Volume::new(desc, VolumeData::U16(v)).expect("a blob channel")
}

/// `n` (1 to 4) blob channels, each's blob in another place.
pub fn blob_channels(n: usize) -> Vec<Volume> {
    let centres = [
        [0.3, 0.35, 0.4],
        [0.7, 0.6, 0.5],
        [0.45, 0.7, 0.65],
        [0.6, 0.3, 0.3],
    ];
    (0..n.min(4))
        .map(|c| blob_channel(centres[c], 1.0 - 0.1 * c as f32))
        .collect()
}

/// A style per blob channel: its colour of [`COLORS`] through the window
/// `[0.08, 0.7]` at opacity 0.6, isovalue 0.45.
pub fn blob_styles(n: usize) -> Vec<ChannelStyle> {
    (0..n)
        .map(|c| ChannelStyle::window(COLORS[c % 4], [0.08, 0.7], 0.6).with_isovalue(0.45))
        .collect()
}

/// Distinct channel colours (green, magenta, cyan, yellow).
pub const COLORS: [[f32; 3]; 4] = [
    [0.1, 1.0, 0.2],
    [1.0, 0.2, 0.9],
    [0.2, 0.8, 1.0],
    [1.0, 0.9, 0.1],
];

/// The shared confocal nuclei (u16, 256x256x60) and transformed copies of
/// it as `n` (1 to 4) channels: the nuclei; mirrored in x; its values
/// shifted up by a quarter of its range (clamped); mirrored in y. `None`
/// without ../shared (see [`crate::shared_data_dir`]).
pub fn nuclei_channels(n: usize) -> Option<ChannelVolume> {
    let path = crate::shared_volume("cells3d_nuclei_fluo")?;
    let nuclei = brickray_io::read_volume(&path).unwrap_or_else(|e| panic!("{e}"));
    let [nx, ny, nz] = nuclei.dims().map(|x| x as usize);
    let at = |x: usize, y: usize, z: usize| nuclei.data().get((z * ny + y) * nx + x);
    let (lo, hi) = nuclei.data().min_max().expect("a volume has samples");
    let copy = |f: &dyn Fn(usize, usize, usize) -> f32| {
        let mut data = Vec::with_capacity(nx * ny * nz);
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    data.push(f(x, y, z).clamp(0.0, 65535.0) as u16);
                }
            }
        }
        Volume::new(nuclei.desc().clone(), VolumeData::U16(data)).expect("same grid")
    };
    let all = [
        nuclei.clone(),
        copy(&|x, y, z| at(nx - 1 - x, y, z)),
        copy(&|x, y, z| at(x, y, z) + 0.25 * (hi - lo)),
        copy(&|x, y, z| at(x, ny - 1 - y, z)),
    ];
    Some(ChannelVolume::new(all[..n.clamp(1, 4)].to_vec()).expect("1 to 4 channels of one grid"))
}

/// A style per channel: its colour of [`COLORS`] through the window
/// `[0.15, 0.6]` at opacity 0.4, isovalue 0.35.
pub fn nuclei_styles(n: usize) -> Vec<ChannelStyle> {
    (0..n)
        .map(|c| ChannelStyle::window(COLORS[c % 4], [0.15, 0.6], 0.4).with_isovalue(0.35))
        .collect()
}

/// The modes the channel tests and bench draw, by name: DVR, shaded DVR,
/// MIP and iso (the mode's isovalue `iso`; the channels' own isovalues are
/// what the multi-channel kernel uses), at `step_factor`.
pub fn modes(step_factor: f32, iso: f32) -> Vec<(&'static str, brickray_core::RenderSettings)> {
    use brickray_core::{RenderMode, RenderSettings, Shading};
    let base = RenderSettings {
        step_factor,
        ..Default::default()
    };
    let shading = Shading {
        enabled: true,
        ..Default::default()
    };
    let with = |mode| RenderSettings { mode, ..base };
    vec![
        ("dvr", base),
        ("dvr shaded", RenderSettings { shading, ..base }),
        ("mip", with(RenderMode::Mip)),
        (
            "iso",
            with(RenderMode::Iso {
                value: iso,
                color: [1.0; 3],
            }),
        ),
    ]
}
