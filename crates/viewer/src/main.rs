//! brickray's interactive viewer: `brickray-viewer [PATH] [--script FILE]`.
//!
//! Opens a raw+JSON or NRRD volume (loaded whole when small, built into a
//! brick store in the background when large), a brick store (`.brs`), or with
//! no argument a procedural 4096^3 Mandelbulb streamed out of core. The volume is
//! drawn through egui-wgpu's paint callback: the viewer is a brickray host like
//! any other. See `docs/viewer.md`.

mod app;
mod script;
mod source;
mod stats;
mod tf;
mod tf_widget;

use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};

/// Command line.
#[derive(Debug, Parser)]
#[command(
    name = "brickray-viewer",
    version,
    about = "Interactive out-of-core volume viewer (brickray)"
)]
struct Cli {
    /// A volume (.json sidecar, .raw, .nrrd, .nhdr, NIfTI .nii/.nii.gz, TIFF
    /// .tif/.tiff, a DICOM series folder, OME-Zarr .zarr), a brick store
    /// (.brs) or its URL (s3://, gs://, az://, https://; docs/remote.md),
    /// `bulb:N` (a Mandelbulb, N^3 voxels computed on demand) or
    /// `procedural:N` (fractal noise, N^3 voxels). Default: bulb:4096.
    path: Option<String>,
    /// Run the actions of FILE (see docs/viewer.md); the exit status says
    /// whether they all succeeded.
    #[arg(long, value_name = "FILE")]
    script: Option<PathBuf>,
    /// Window size in pixels, WIDTHxHEIGHT.
    #[arg(long, default_value = "1280x800", value_parser = parse_size)]
    window: (u32, u32),
    /// Volume files up to this many MiB are loaded whole (in core); larger
    /// ones are built into a brick store and streamed.
    #[arg(long, default_value_t = 1024, value_name = "MiB")]
    in_core_max: u64,
    /// Where brick stores built from large files go.
    #[arg(long, value_name = "DIR")]
    store_dir: Option<PathBuf>,
    /// GPU brick pool of the out-of-core path, MiB.
    #[arg(long, default_value_t = 256, value_name = "MiB")]
    gpu_pool: u64,
    /// CPU brick cache of the out-of-core path, MiB.
    #[arg(long, default_value_t = 1024, value_name = "MiB")]
    cpu_cache: u64,
    /// Open the volume as a label map (a segmentation of u8, u16 or u32
    /// ids; docs/labels.md). A sidecar with `"kind": "labels"` or a
    /// `labels` list, and a label store, are label maps anyway. A colour
    /// table beside it (NAME.lut, mricron's, or NAME.labels.json) is loaded.
    #[arg(long)]
    labels: bool,
    /// Draw coarse levels with their spread (docs/rendering-model.md,
    /// "Coarse levels"): brick stores built from large files record each
    /// coarse voxel's spread (format version 7), and a store without them
    /// is built again. A store that records spreads is always drawn with
    /// them. Intensity volumes only.
    #[arg(long)]
    spread: bool,
    /// Whether streamed volumes keep each texel's gradient on the GPU, so
    /// that shaded DVR reads one texel per sample instead of six (about 0.7x
    /// the shaded frame; docs/rendering-model.md, "Shading"): `auto` where
    /// the GPU pool (`--gpu-pool`) holds every brick of the volume with them,
    /// `always` (what `--gradients` alone asks; the pool then holds fewer
    /// bricks: 8 more bytes per stored voxel), or `never`. A value is given
    /// as `--gradients=never`, so that `--gradients PATH` still opens PATH.
    #[arg(
        long,
        value_enum,
        default_value_t = Gradients::Auto,
        num_args = 0..=1,
        require_equals = true,
        default_missing_value = "always"
    )]
    gradients: Gradients,
    /// Draw this label map over the image in the same rays (colours over the
    /// image's TF; docs/labels.md): placed where both files say (their
    /// affines when both give one, else both from the grid's origin at their
    /// spacing). Its colour table beside it is loaded, as for `--labels`. A
    /// label store (.brs) gives its finest level that fits one texture.
    #[arg(long, value_name = "LABELS")]
    overlay: Option<PathBuf>,
}

/// `--gradients`: [`brickray::KeepGradients`] by its command-line name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Gradients {
    Auto,
    Always,
    Never,
}

impl From<Gradients> for brickray::KeepGradients {
    fn from(g: Gradients) -> Self {
        match g {
            Gradients::Auto => brickray::KeepGradients::WhenEveryBrickFits,
            Gradients::Always => brickray::KeepGradients::Always,
            Gradients::Never => brickray::KeepGradients::Never,
        }
    }
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or("expected WIDTHxHEIGHT, e.g. 1280x800")?;
    let p = |v: &str| v.parse::<u32>().ok().filter(|&n| (64..=16384).contains(&n));
    match (p(w), p(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err("width and height must be in 64..=16384".into()),
    }
}

fn main() -> ExitCode {
    ensure_runtime_dir();
    let cli = Cli::parse();
    let script = match &cli.script {
        None => None,
        Some(path) => match std::fs::read_to_string(path)
            .map_err(|e| format!("{}: {e}", path.display()))
            .and_then(|t| script::parse(&t).map_err(|e| format!("{}: {e}", path.display())))
        {
            Ok(actions) => Some(actions),
            Err(e) => {
                eprintln!("brickray-viewer: {e}");
                return ExitCode::from(2);
            }
        },
    };
    // With a script that opens its own volume, open nothing first.
    let input = match (&cli.path, &script) {
        (Some(p), _) => Some(p.as_str()),
        (None, Some(a)) if a.iter().any(|a| matches!(a, script::Action::Open(_))) => None,
        (None, _) => Some("bulb"),
    };
    let input = match input.map(source::Input::parse).transpose() {
        Ok(i) => i,
        Err(e) => {
            eprintln!("brickray-viewer: {e}");
            return ExitCode::from(2);
        }
    };
    let store_dir = cli
        .store_dir
        .clone()
        .unwrap_or_else(|| std::env::temp_dir().join("brickray-viewer-stores"));
    let outcome = Arc::new(Mutex::new(None));
    let startup = app::Startup {
        input,
        script,
        outcome: outcome.clone(),
        open: source::OpenOptions {
            in_core_max_bytes: cli.in_core_max << 20,
            // Replaced by the device's 3D texture limit once it exists.
            max_3d_side: 2048,
            store_dir,
            labels: cli.labels,
            spread: cli.spread,
        },
        overlay: cli.overlay.clone(),
        streamed_gradients: cli.gradients.into(),
        ooc: brickray::OutOfCoreConfig {
            gpu_budget_bytes: cli.gpu_pool << 20,
            cpu_budget_bytes: cli.cpu_cache << 20,
            ..Default::default()
        },
    };
    let has_script = startup.script.is_some();
    let mut wgpu_options = eframe::egui_wgpu::WgpuConfiguration::default();
    if let eframe::egui_wgpu::WgpuSetup::CreateNew(create) = &mut wgpu_options.wgpu_setup {
        create.device_descriptor = Arc::new(app::device_descriptor);
    }
    let options = eframe::NativeOptions {
        viewport: eframe::egui::ViewportBuilder::default()
            .with_title("brickray viewer")
            .with_inner_size([cli.window.0 as f32, cli.window.1 as f32]),
        // egui's pass gets a depth buffer: the volume and the viewer's own
        // geometry composite by depth in it.
        depth_buffer: 32,
        // Exact colours (screenshots are compared with the library's images).
        dithering: false,
        wgpu_options,
        ..Default::default()
    };
    let run = eframe::run_native(
        "brickray-viewer",
        options,
        Box::new(move |cc| Ok(Box::new(app::ViewerApp::new(cc, startup)))),
    );
    if let Err(e) = run {
        eprintln!("brickray-viewer: {e}");
        return ExitCode::FAILURE;
    }
    if has_script {
        match outcome.lock().ok().and_then(|mut o| o.take()) {
            Some(Ok(())) => {}
            Some(Err(e)) => {
                eprintln!("brickray-viewer: script failed: {e}");
                return ExitCode::FAILURE;
            }
            None => {
                eprintln!("brickray-viewer: the window closed before the script finished");
                return ExitCode::FAILURE;
            }
        }
    }
    ExitCode::SUCCESS
}

/// Gives the process a private `XDG_RUNTIME_DIR` when the environment has
/// none (a bare X server, a container, CI under Xvfb): Mesa's Vulkan
/// device-selection layer looks for a Wayland display through it when a
/// window's surface is made, and prints `XDG_RUNTIME_DIR is invalid or not
/// set` three times on every launch without it. One that is set and is a
/// directory is kept.
#[allow(unsafe_code)]
fn ensure_runtime_dir() {
    let valid =
        std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| std::path::Path::new(&d).is_dir());
    if valid {
        return;
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
        let uid = std::fs::metadata("/proc/self")
            .map(|m| m.uid())
            .unwrap_or(0);
        let dir = std::env::temp_dir().join(format!("brickray-runtime-{uid}"));
        let _ = std::fs::DirBuilder::new().mode(0o700).create(&dir);
        // Only a directory of ours that no one else can read (as the XDG
        // specification asks of a runtime directory).
        let ours = std::fs::symlink_metadata(&dir)
            .is_ok_and(|m| m.is_dir() && m.uid() == uid && m.permissions().mode() & 0o077 == 0);
        if ours {
            // SAFETY: the first thing `main` does, before any other thread
            // exists, so nothing reads the environment concurrently.
            unsafe { std::env::set_var("XDG_RUNTIME_DIR", &dir) };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--gradients` alone is `always` and leaves a path after it a path; a
    /// value goes after `=`; without the flag, `auto`.
    #[test]
    fn gradients_take_a_value_only_after_an_equals_sign() {
        let parse = |args: &[&str]| Cli::try_parse_from(args).expect("valid arguments");
        let c = parse(&["brickray-viewer", "--gradients", "head.brs"]);
        assert_eq!(c.gradients, Gradients::Always);
        assert_eq!(c.path.as_deref(), Some("head.brs"));
        assert_eq!(
            parse(&["brickray-viewer", "--gradients=never"]).gradients,
            Gradients::Never
        );
        assert_eq!(
            parse(&["brickray-viewer", "head.brs"]).gradients,
            Gradients::Auto
        );
        assert!(Cli::try_parse_from(["brickray-viewer", "--gradients=sometimes"]).is_err());
    }
}
