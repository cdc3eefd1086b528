use super::*;

#[test]
fn every_action_parses() {
    let text = "
        # a comment
        open /data/head ct.json
        open procedural:256
        tf ct-bone
        tf load my tf.json   # trailing comment
        mode dvr
        mode iso 0.35
        iso 0.4
        step 0.25
        camera orbit 30 20 1.5
        camera axis -y
        camera reset
        projection orthographic
        overlays off
        background 0 0 0
        clip 0 0 0.5 1 1 1
        bricks 300
        bricks off
        lod geometric 0.5
        lod visible
        lod visible 16
        visibility rayguided
        prediction exact
        wait 3
        wait converged
        wait converged 50
        screenshot out/a.png
        screenshot-window out/w.png
        layout four
        crosshair 10 20.5 3
        layout single
        window 40 80
        window bone
        window auto
        window off
        quit
        labels show-only 3 5 7
        labels show-all
        labels select 9
        labels select none
        labels opacity 0.25
        labels table atlas.nii.lut
        pick 10 20
        overlay atlas.json
        overlay mode mask
        overlay mode colour
        overlay opacity 0.5
        overlay off
        camera view a
        camera view inferior
        termination 0.95
        termination off
        skipping off
        preint on
        adaptive on
    ";
    let a = parse(text).unwrap();
    assert_eq!(a.len(), 54);
    assert_eq!(a[47], Action::View(Direction::Anterior));
    assert_eq!(a[48], Action::View(Direction::Inferior));
    assert_eq!(
        a[49..],
        [
            Action::Termination(Some(0.95)),
            Action::Termination(None),
            Action::Skipping(false),
            Action::Preint(true),
            Action::AdaptiveStep(true),
        ]
    );
    assert_eq!(
        a[42],
        Action::Overlay(OverlayAction::Open("atlas.json".into()))
    );
    assert_eq!(a[43], Action::Overlay(OverlayAction::Mask(true)));
    assert_eq!(a[44], Action::Overlay(OverlayAction::Mask(false)));
    assert_eq!(a[45], Action::Overlay(OverlayAction::Opacity(0.5)));
    assert_eq!(a[46], Action::Overlay(OverlayAction::Off));
    assert_eq!(a[41], Action::Pick([10, 20]));
    assert_eq!(a[35], Action::Labels(LabelAction::ShowOnly(vec![3, 5, 7])));
    assert_eq!(a[36], Action::Labels(LabelAction::ShowAll));
    assert_eq!(a[37], Action::Labels(LabelAction::Select(vec![9])));
    assert_eq!(a[38], Action::Labels(LabelAction::Select(Vec::new())));
    assert_eq!(a[39], Action::Labels(LabelAction::Opacity(0.25)));
    assert_eq!(
        a[40],
        Action::Labels(LabelAction::Table("atlas.nii.lut".into()))
    );
    for bad in [
        "labels show-only x",
        "labels opacity 2",
        "labels select",
        "labels",
        "overlay opacity 1.5",
        "overlay mode",
        "overlay",
        "termination 0",
        "termination 1.5",
        "termination nan",
        "preint yes",
        "adaptive",
        "skipping",
    ] {
        assert!(parse(bad).is_err(), "{bad}");
    }
    assert_eq!(a[26], Action::WindowScreenshot("out/w.png".into()));
    assert_eq!(a[27], Action::FourViews(true));
    assert_eq!(a[28], Action::Crosshair([10.0, 20.5, 3.0]));
    assert_eq!(a[29], Action::FourViews(false));
    assert_eq!(a[30], Action::Window(WindowChoice::CentreWidth(40.0, 80.0)));
    assert_eq!(
        a[31],
        Action::Window(WindowChoice::Preset(brickray::CtPreset::Bone))
    );
    assert_eq!(a[32], Action::Window(WindowChoice::Auto));
    assert_eq!(a[33], Action::Window(WindowChoice::Off));
    assert_eq!(
        a[20],
        Action::Visibility(brickray::VisibilityPolicy::RayGuided)
    );
    assert_eq!(a[21], Action::Prediction(PredictionChoice::Exact));
    assert_eq!(
        a[17],
        Action::Lod(brickray::LodMetric::Geometric, Some(0.5))
    );
    assert_eq!(
        a[18],
        Action::Lod(
            brickray::LodMetric::VisibleError {
                budget: DEFAULT_ERROR_BUDGET
            },
            None
        )
    );
    assert_eq!(
        a[19],
        Action::Lod(brickray::LodMetric::VisibleError { budget: 16.0 }, None)
    );
    assert_eq!(a[15], Action::Bricks(Some(300)));
    assert_eq!(a[16], Action::Bricks(None));
    assert_eq!(a[0], Action::Open("/data/head ct.json".into()));
    assert_eq!(a[3], Action::TfLoad("my tf.json".into()));
    assert_eq!(a[5], Action::Mode(ModeName::Iso, Some(0.35)));
    assert_eq!(a[8], Action::Orbit(30.0, 20.0, 1.5));
    assert_eq!(a[9], Action::Axis(Axis::NegY));
    assert_eq!(a[13], Action::Background([0, 0, 0]));
    assert_eq!(a[23], Action::WaitConverged(600));
    assert_eq!(a[24], Action::WaitConverged(50));
    assert_eq!(a[14], Action::Clip([0.0, 0.0, 0.5], [1.0; 3]));
    assert_eq!(a[34], Action::Quit);
}

#[test]
fn every_prediction_choice_is_valid_and_only_exact_guards() {
    for c in PredictionChoice::ALL {
        if let Some(p) = c.settings() {
            p.validate().unwrap();
            assert_eq!(p.guard, c == PredictionChoice::Exact, "{c:?}");
        } else {
            assert_eq!(c, PredictionChoice::Off);
        }
    }
}

#[test]
fn bad_lines_name_their_line() {
    for (text, line) in [
        ("open", 1),
        ("\nmode volume", 2),
        ("iso 1.5", 1),
        ("iso nan", 1),
        ("step 100", 1),
        ("camera orbit 1 2 0", 1),
        ("camera axis w", 1),
        ("camera view x", 1),
        ("tf nope", 1),
        ("tf load", 1),
        ("background 0 0 300", 1),
        ("wait x", 1),
        ("overlays maybe", 1),
        ("layout three", 1),
        ("window 40 0", 1),
        ("window 40", 1),
        ("window spine", 1),
        ("crosshair 1 2", 1),
        ("crosshair 1 2 nan", 1),
        ("u8 slow", 1),
        ("clip 0.5 0 0 0.4 1 1", 1),
        ("clip 0 0 0 1 1", 1),
        ("bricks 0", 1),
        ("bricks many", 1),
        ("lod fast", 1),
        ("lod visible -1", 1),
        ("lod visible x", 1),
        ("lod error", 1),
        ("lod geometric 1 2", 1),
        ("visibility some", 1),
        ("prediction on", 1),
        ("\n\n\nfly away", 4),
    ] {
        let e = parse(text).unwrap_err();
        assert_eq!(e.line, line, "{text:?}: {e}");
    }
}

#[test]
fn channel_lines_parse() {
    let a = parse(
        "channel 1 visible off\nchannel 0 window 100 2500.5\nchannel 2 color 255 0 128\n\
         channel 3 colour 00FF80\nchannel 0 opacity 0.25\nchannel 1 iso 1200",
    )
    .unwrap();
    assert_eq!(
        a,
        [
            Action::Channel(1, ChannelEdit::Visible(false)),
            Action::Channel(0, ChannelEdit::Window(100.0, 2500.5)),
            Action::Channel(2, ChannelEdit::Color([1.0, 0.0, 128.0 / 255.0])),
            Action::Channel(3, ChannelEdit::Color([0.0, 1.0, 128.0 / 255.0])),
            Action::Channel(0, ChannelEdit::Opacity(0.25)),
            Action::Channel(1, ChannelEdit::Iso(1200.0)),
        ]
    );
    for bad in [
        "channel 4 visible on",
        "channel x visible on",
        "channel 0",
        "channel 0 visible maybe",
        "channel 0 window 10",
        "channel 0 window 20 10",
        "channel 0 window 0 nan",
        "channel 0 color 0 0 256",
        "channel 0 color GG0000",
        "channel 0 color 00FF",
        "channel 0 opacity 1.5",
        "channel 0 iso",
        "channel 0 gamma 2",
    ] {
        let e = parse(&format!("\n{bad}")).unwrap_err();
        assert_eq!(e.line, 2, "{bad}: {e}");
    }
}

#[test]
fn lod_octants_parses() {
    let a = parse("lod octants 8\nlod octants").unwrap();
    assert_eq!(
        a[0],
        Action::Lod(brickray::LodMetric::VisibleOctants { budget: 8.0 }, None)
    );
    assert_eq!(
        a[1],
        Action::Lod(
            brickray::LodMetric::VisibleOctants {
                budget: DEFAULT_ERROR_BUDGET
            },
            None
        )
    );
}
