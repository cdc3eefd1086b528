//! Tests of cameras, rays, depth conventions and volume frames.

use super::*;

#[test]
fn centered_frame_keeps_proportions() {
    let f = VolumeFrame::centered([256, 256, 108], [0.957, 0.957, 1.5]);
    let s = f.world_size();
    assert!((s.x - 1.0).abs() < 1e-6);
    assert!((s.z - 108.0 * 1.5 / (256.0 * 0.957)).abs() < 1e-5);
    assert!(f.center().length() < 1e-6);
    assert!((f.voxel_world - 1.0 / 256.0).abs() < 1e-6);
    assert_eq!(f.validate(), Ok(()));
}

#[test]
fn centre_ray_hits_box() {
    let cam = Camera::orbit(Vec3::ZERO, 3.0, 0.0, 0.0);
    let f = VolumeFrame::centered([8, 8, 8], [1.0; 3]);
    let im = f.model.as_dmat4().inverse();
    let r = cam.rays(1.0).pixel_ray(&im, 31.5, 31.5, 64, 64);
    let (t0, t1) = r.clip_unit_box().unwrap();
    assert!((t1 - t0 - 1.0).abs() < 1e-3, "{t0} {t1}");
}

fn cameras() -> Vec<Camera> {
    let mut out = Vec::new();
    for depth in [DepthConvention::Standard, DepthConvention::ReversedZ] {
        for far in [7.0, f32::INFINITY] {
            for near in [0.5, 1e-3, 1e-6] {
                let mut c = Camera::orbit(Vec3::new(0.1, -0.2, 0.3), 3.0, 0.7, 0.4);
                c.near = near;
                c.far = far;
                c.depth = depth;
                out.push(c);
                if far.is_finite() {
                    c.projection = Projection::Orthographic { height: 1.3 };
                    out.push(c);
                }
            }
        }
    }
    out
}

/// The basis rays agree with the projection matrix: a point at `t` projects
/// back to the pixel's NDC and to the depth of `depth_at`, in every convention.
#[test]
fn rays_and_depth_agree_with_the_projection_matrix() {
    for cam in cameras() {
        cam.validate().unwrap();
        let aspect = 1.5;
        let vp = cam.view_proj(aspect as f32).as_dmat4();
        let g = cam.rays(aspect);
        for (x, y) in [(0.0, 0.0), (0.9, -0.7), (-0.3, 0.99)] {
            let r = g.ray(&DMat4::IDENTITY, (x, y));
            assert!((r.dir.length() - 1.0).abs() < 1e-12);
            // The origin lies on the near plane.
            assert!(((r.origin - g.eye).dot(g.fwd) - g.near).abs() < 1e-9 * (1.0 + g.near));
            for t in [0.5, 2.0, 3.0] {
                let p = r.origin + r.dir * t;
                let c = vp * p.extend(1.0);
                let ndc = c.truncate() / c.w;
                assert!(
                    (ndc.x - x).abs() < 1e-4 && (ndc.y - y).abs() < 1e-4,
                    "{cam:?}"
                );
                let want = ndc.z.clamp(0.0, 1.0);
                let got = g.depth_at(&r, t);
                assert!((got - want).abs() < 1e-5, "{cam:?}: {got} vs {want}");
                if got > 0.0 && got < 1.0 {
                    let back = g.t_at_depth(&r, got);
                    assert!((back - t).abs() < 1e-6 * t, "{cam:?}: t {t} back {back}");
                }
            }
        }
    }
}

/// The near plane maps to the near end of the convention, the far plane to
/// the far end; the far end of an infinite projection is infinitely far.
#[test]
fn conventions_put_near_and_far_at_the_right_ends() {
    for cam in cameras() {
        let m = cam.depth_map();
        let near = m.depth(cam.near as f64);
        let far = m.depth(if cam.far.is_finite() {
            cam.far as f64
        } else {
            1e300
        });
        let (n_want, f_want) = match cam.depth {
            DepthConvention::Standard => (0.0, 1.0),
            DepthConvention::ReversedZ => (1.0, 0.0),
        };
        assert!((near - n_want).abs() < 1e-9, "{cam:?}");
        assert!((far - f_want).abs() < 1e-9, "{cam:?}");
        assert_eq!(cam.depth.far_value() as f64, f_want);
        if cam.far.is_infinite() {
            assert_eq!(m.distance(f_want), f64::INFINITY);
        }
    }
}

#[test]
fn degenerate_cameras_are_typed_errors() {
    let ok = Camera::orbit(Vec3::ZERO, 2.0, 0.3, 0.2);
    type Check = fn(&CameraError) -> bool;
    let cases: Vec<(Camera, Check)> = vec![
        (
            Camera {
                eye: Vec3::NAN,
                ..ok
            },
            |e| matches!(e, CameraError::NotFinite { field: "eye" }),
        ),
        (
            Camera {
                up: Vec3::new(f32::INFINITY, 0.0, 0.0),
                ..ok
            },
            |e| matches!(e, CameraError::NotFinite { field: "up" }),
        ),
        (
            Camera {
                target: ok.eye,
                ..ok
            },
            |e| matches!(e, CameraError::EyeAtTarget { .. }),
        ),
        (
            Camera {
                up: ok.target - ok.eye,
                ..ok
            },
            |e| matches!(e, CameraError::UpParallelToView { .. }),
        ),
        (
            Camera {
                up: Vec3::ZERO,
                ..ok
            },
            |e| matches!(e, CameraError::UpParallelToView { .. }),
        ),
        (
            Camera {
                projection: Projection::Perspective { fov_y: 0.0 },
                ..ok
            },
            |e| matches!(e, CameraError::BadFieldOfView { .. }),
        ),
        (
            Camera {
                projection: Projection::Perspective { fov_y: f32::NAN },
                ..ok
            },
            |e| matches!(e, CameraError::BadFieldOfView { .. }),
        ),
        (
            Camera {
                projection: Projection::Perspective { fov_y: 3.2 },
                ..ok
            },
            |e| matches!(e, CameraError::BadFieldOfView { .. }),
        ),
        (
            Camera {
                projection: Projection::Orthographic { height: 0.0 },
                ..ok
            },
            |e| matches!(e, CameraError::BadOrthographicHeight { .. }),
        ),
        (Camera { near: 0.0, ..ok }, |e| {
            matches!(e, CameraError::BadNear { .. })
        }),
        (
            Camera {
                near: f32::NAN,
                ..ok
            },
            |e| matches!(e, CameraError::BadNear { .. }),
        ),
        (Camera { far: ok.near, ..ok }, |e| {
            matches!(e, CameraError::BadFar { .. })
        }),
        (
            Camera {
                far: f32::NAN,
                ..ok
            },
            |e| matches!(e, CameraError::BadFar { .. }),
        ),
        (
            Camera {
                far: f32::INFINITY,
                projection: Projection::Orthographic { height: 1.0 },
                ..ok
            },
            |e| matches!(e, CameraError::BadFar { .. }),
        ),
    ];
    for (cam, want) in cases {
        let e = cam.validate().expect_err("must be refused");
        assert!(want(&e), "{cam:?}: {e}");
    }
    assert_eq!(
        Camera {
            far: f32::INFINITY,
            ..ok
        }
        .validate(),
        Ok(())
    );
}

#[test]
fn degenerate_frames_are_typed_errors() {
    let f = VolumeFrame::centered([8, 8, 8], [1.0; 3]);
    assert_eq!(
        VolumeFrame {
            model: Mat4::ZERO,
            ..f
        }
        .validate(),
        Err(FrameError::Singular { determinant: 0.0 })
    );
    assert!(
        VolumeFrame {
            model: Mat4::from_scale(Vec3::new(1.0, 1.0, 0.0)),
            ..f
        }
        .validate()
        .is_err()
    );
    assert_eq!(
        VolumeFrame {
            model: Mat4::NAN,
            ..f
        }
        .validate(),
        Err(FrameError::NotFinite)
    );
    assert!(matches!(
        VolumeFrame {
            voxel_world: 0.0,
            ..f
        }
        .validate(),
        Err(FrameError::BadVoxelSize { .. })
    ));
}
