//! The check of `embed_headless`: the written PNG shows what it should.

/// The written PNG shows the background, the floor where no volume is in
/// front of it, and the volume blended over the floor at the ball's centre.
#[test]
fn writes_the_composited_image() {
    let out = std::env::temp_dir().join(format!(
        "brickray-embed-headless-{}.png",
        std::process::id()
    ));
    let camera = super::run(&out).expect("render");
    let img = image::open(&out).expect("read the PNG").to_rgb8();
    let _ = std::fs::remove_file(&out);
    let (w, h) = super::SIZE;
    let vp = camera.view_proj(w as f32 / h as f32);
    let px = |p: glam::Vec3| {
        let c = vp.project_point3(p);
        let (x, y) = ((c.x + 1.0) * 0.5 * w as f32, (1.0 - c.y) * 0.5 * h as f32);
        img.get_pixel(x as u32, y as u32).0
    };
    let near = |a: [u8; 3], b: [u8; 3]| a.iter().zip(b).all(|(x, y)| x.abs_diff(y) <= 1);
    assert!(
        near(img.get_pixel(2, 2).0, [0, 0, 0]),
        "corner is background"
    );
    // A floor point between the eye and the volume's box: nothing in front.
    assert!(
        near(px(glam::Vec3::new(0.0, 0.0, 0.75)), super::FLOOR),
        "floor visible"
    );
    // The ball's centre lies on the floor: the ball's upper half is in front.
    let centre = px(glam::Vec3::ZERO);
    assert!(!near(centre, super::FLOOR), "volume over floor: {centre:?}");
    // The ball's top, above the floor: volume over the background.
    let top = px(glam::Vec3::new(0.0, 0.25, 0.0));
    assert!(!near(top, [0, 0, 0]), "volume above floor: {top:?}");
}
