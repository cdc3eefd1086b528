//! The `formats` suite: store build throughput from each input format, on the
//! fixtures of `shared/data/formats` (each the same volume as a shared raw
//! file, built from that raw file too for comparison), and peak RSS under a
//! memory bound smaller than the volumes, so that the readers' streaming is
//! what is measured.
//!
//! `cargo run --release -p brickray-bench -- formats [--memory-mib N] [--rounds N]`
//!
//! Time is wall clock from opening the input (the readers' one validating
//! pass for the value range included) to the renamed store; best of
//! `--rounds` (default 3). Peak RSS is the process's `VmHWM`, reset before
//! each build.

use crate::build::peak_rss_mb;
use brickray_io::ReadOptions;
use brickray_store::BuildOptions;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The builder's memory bound, MiB.
    #[arg(long, default_value_t = 8)]
    memory_mib: u64,
    /// Best of this many builds.
    #[arg(long, default_value_t = 3, value_parser = crate::at_least_one::<u64>)]
    rounds: u64,
}

/// One input's build.
#[derive(Debug, Serialize)]
pub(crate) struct Row {
    /// The input, as printed.
    input: &'static str,
    /// Input voxels per second of the best build, millions.
    mvoxel_per_s: f64,
    /// Input bytes per second of the best build, MB.
    mb_per_s: f64,
    /// The best build's wall time and the fastest open, s.
    build_s: f64,
    open_s: f64,
    /// Peak RSS over the builds, MiB.
    peak_rss_mb: f64,
    /// The builder's own estimate of its buffers, MiB.
    builder_estimate_mib: f64,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct FormatsResult {
    memory_bound_mb: u64,
    rounds: u64,
    rows: Vec<Row>,
}

pub(crate) fn run(args: &Args) -> Result<FormatsResult, String> {
    let (memory_mib, rounds) = (args.memory_mib, args.rounds);
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    if !data.is_dir() {
        return Err(format!("shared data not found at {}", data.display()));
    }
    let f = data.join("formats");
    let raw = |n: &str| data.join(n).join(format!("{n}.json"));
    let inputs: Vec<(&'static str, PathBuf)> = vec![
        (
            "raw pycortex_s1_t1_mri (u8 256^3)",
            raw("pycortex_s1_t1_mri"),
        ),
        (
            "NIfTI-1 .nii.gz (same volume)",
            f.join("nifti/pycortex_s1_t1.nii.gz"),
        ),
        (
            "OME-Zarr 0.5 zstd (same volume)",
            f.join("ome-zarr/pycortex_s1_t1_v05.ome.zarr"),
        ),
        ("raw cryoet_tomo (f32 135x135x101)", raw("cryoet_tomo")),
        (
            "TIFF slice folder (same volume)",
            f.join("tiff_slices/cryoet_tomo"),
        ),
        (
            "OME-Zarr 0.4 blosc (same volume)",
            f.join("ome-zarr/cryoet_tomo_v04.ome.zarr"),
        ),
        (
            "raw cells3d_nuclei_fluo (u16 256x256x60)",
            raw("cells3d_nuclei_fluo"),
        ),
        (
            "TIFF stack (same volume)",
            f.join("tiff/cells3d_nuclei.tif"),
        ),
        (
            "raw invesalius_cranium_ct (i16 256x256x108)",
            raw("invesalius_cranium_ct"),
        ),
        (
            "DICOM series, 108 files (same volume)",
            f.join("dicom/cranium_ct"),
        ),
    ];
    let tmp = tempfile::tempdir().map_err(|e| e.to_string())?;
    let opts = BuildOptions {
        memory_bound: memory_mib << 20,
        progress: None,
        ..Default::default()
    };
    let mut rows = Vec::new();
    println!("memory bound {memory_mib} MiB, best of {rounds}");
    for (k, &(label, ref path)) in inputs.iter().enumerate() {
        let mut best = f64::INFINITY;
        let mut rss = 0.0f64;
        let mut est = 0u64;
        let mut open_s = f64::INFINITY;
        let mut bytes = 0u64;
        let mut voxels = 0u64;
        for _ in 0..rounds {
            let _ = std::fs::write("/proc/self/clear_refs", "5");
            let t = Instant::now();
            let mut r = brickray_io::open_with(path, &ReadOptions::default())
                .map_err(|e| format!("{label}: {e}"))?;
            let opened = t.elapsed().as_secs_f64();
            let out = tmp.path().join(format!("{k}.brick"));
            let rep = brickray_store::build(r.as_mut(), &out, &opts)
                .map_err(|e| format!("{label}: {e}"))?;
            let s = t.elapsed().as_secs_f64();
            best = best.min(s);
            open_s = open_s.min(opened);
            rss = rss.max(peak_rss_mb());
            est = rep.buffer_estimate;
            bytes = rep.input_bytes;
            voxels = rep.input_voxels;
        }
        let mvox = voxels as f64 / best / 1e6;
        println!(
            "{label:<46} {mvox:>7.1} Mvoxel/s  {:>6.1} MB/s  {best:>6.3} s (open {open_s:.3} s)  peak RSS {rss:>6.1} MiB  builder estimate {:.1} MiB",
            bytes as f64 / best / 1e6,
            est as f64 / (1 << 20) as f64
        );
        let r1 = |x: f64| (x * 10.0).round() / 10.0;
        rows.push(Row {
            input: label,
            mvoxel_per_s: r1(mvox),
            mb_per_s: r1(bytes as f64 / best / 1e6),
            build_s: (best * 1e3).round() / 1e3,
            open_s: (open_s * 1e3).round() / 1e3,
            peak_rss_mb: r1(rss),
            builder_estimate_mib: r1(est as f64 / (1 << 20) as f64),
        });
    }
    Ok(FormatsResult {
        memory_bound_mb: memory_mib,
        rounds,
        rows,
    })
}
