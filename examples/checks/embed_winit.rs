//! The check of `embed_winit`: a window opens and a frame is drawn.

/// Opens the window (an X server is needed: CI runs the tests under Xvfb),
/// draws one frame on the surface and closes.
#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn opens_a_window_and_draws_a_frame() {
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true but no display (run under xvfb-run)"
        );
        eprintln!("skipping: no display (DISPLAY unset)");
        return;
    }
    use winit::platform::x11::EventLoopBuilderExtX11;
    let event_loop = winit::event_loop::EventLoop::builder()
        .with_any_thread(true)
        .build();
    let drawn = super::run(event_loop.expect("an event loop"), Some(1)).expect("draw a frame");
    assert_eq!(drawn, 1);
}
