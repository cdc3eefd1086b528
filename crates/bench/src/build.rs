//! The `build` suite: brick-store build throughput and peak RSS, compression
//! ratios, lz4 decode speed and random brick read latency.
//!
//! `cargo run --release -p brickray-bench -- build [--quick] [--keep] [--smoke]`
//!
//! * generated 1024^3 u8 and 1024x1024x540 u16 volumes (written once to a raw
//!   file under the temp dir, then built from it like any input; the file is
//!   in the page cache, so this measures the builder, not the disk);
//! * the four `shared/data` volumes (the head CT timed);
//! * a generated 2048x2048x1024 u8 input (4 GiB) built under the default 1 GiB
//!   memory bound (skipped with `--quick`).
//!
//! `--smoke` shrinks every generated input by 16 per side (64^3, 64x64x33,
//! 128x128x64 under a 1 GiB and a 1 MiB bound, so that the finest level is
//! still built in bands) and reads fewer leaves: a check that the suite
//! runs, in seconds; its figures are not results (the keys keep their
//! names).
//!
//! Peak RSS is the process's `VmHWM`, reset (`/proc/self/clear_refs` = 5)
//! before each build.

use brickray_core::{BrickSource, NodeKey, NodeKind};
use brickray_store::{BuildOptions, Store};
use rayon::prelude::*;
use serde::Serialize;
use serde_json::json;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// The process's peak resident set (`VmHWM`), MiB; NaN where unavailable.
pub(crate) fn peak_rss_mb() -> f64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    s.lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn mix(mut h: u64) -> u64 {
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h
}

/// A phantom: air (0) outside an ellipsoid that fills 94% of the box, nested
/// shells of different values inside with a smooth gradient and a little noise
/// (like a scanned object in air: about half the bricks are uniform air).
fn phantom(dims: [u32; 3], x: u32, y: u32, z: u32, max: f64) -> f64 {
    let p = [x, y, z];
    let d: [f64; 3] = std::array::from_fn(|a| (p[a] as f64 + 0.5) / dims[a] as f64 * 2.0 - 1.0);
    let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() / 0.94;
    if r > 1.0 {
        return 0.0;
    }
    let shell = ((r * 6.0) as u32 % 3) as f64;
    let grad = 0.15 * (x as f64 / dims[0] as f64);
    let noise = (mix((x as u64) | (y as u64) << 21 | (z as u64) << 42) & 15) as f64 / 15.0 * 0.04;
    max * (0.2 + 0.25 * shell + grad + noise)
}

/// Writes a generated raw volume and its JSON sidecar; returns the sidecar path.
fn generate(
    dir: &Path,
    name: &str,
    dims: [u32; 3],
    u16: bool,
    noise: bool,
) -> Result<PathBuf, String> {
    let raw = dir.join(format!("{name}.raw"));
    let json = dir.join(format!("{name}.json"));
    let t = Instant::now();
    let f = std::fs::File::create(&raw).map_err(|e| e.to_string())?;
    let mut w = std::io::BufWriter::with_capacity(8 << 20, f);
    let size = if u16 { 2 } else { 1 };
    let slice = dims[0] as usize * dims[1] as usize * size;
    let per = 16u32;
    let mut z = 0;
    while z < dims[2] {
        let z1 = (z + per).min(dims[2]);
        let mut buf = vec![0u8; (z1 - z) as usize * slice];
        buf.par_chunks_mut(dims[0] as usize * size)
            .enumerate()
            .for_each(|(row, out)| {
                let y = (row % dims[1] as usize) as u32;
                let zz = z + (row / dims[1] as usize) as u32;
                for x in 0..dims[0] {
                    if u16 {
                        let v = phantom(dims, x, y, zz, 60000.0) as u16;
                        out[2 * x as usize..2 * x as usize + 2].copy_from_slice(&v.to_le_bytes());
                    } else if noise {
                        out[x as usize] =
                            mix((x as u64) | (y as u64) << 21 | (zz as u64) << 42) as u8;
                    } else {
                        out[x as usize] = phantom(dims, x, y, zz, 250.0) as u8;
                    }
                }
            });
        w.write_all(&buf).map_err(|e| e.to_string())?;
        z = z1;
    }
    w.flush().map_err(|e| e.to_string())?;
    let max = if u16 { 65535.0 } else { 255.0 };
    let sidecar = json!({
        "dims": dims, "dtype": if u16 { "u16" } else { "u8" }, "spacing": [1.0, 1.0, 1.0],
        "file": format!("{name}.raw"), "byte_order": "little", "value_range": [0.0, max],
    });
    std::fs::write(&json, sidecar.to_string()).map_err(|e| e.to_string())?;
    eprintln!(
        "  generated {name} {dims:?} in {:.1} s",
        t.elapsed().as_secs_f64()
    );
    Ok(json)
}

struct Built {
    mvox_s: f64,
    rss_mb: f64,
    ratio: f64,
    store: PathBuf,
}

fn build_one(input: &Path, out: &Path, opts: &BuildOptions, label: &str) -> Result<Built, String> {
    reset_peak_rss();
    let r = brickray_store::build_file(input, out, opts).map_err(|e| format!("{label}: {e}"))?;
    let rss = peak_rss_mb();
    let mvox_s = r.input_voxels as f64 / r.seconds / 1e6;
    let ratio = r.input_bytes as f64 / r.file_bytes as f64;
    println!(
        "build {label:<28} {:>7.1} Mvoxel/s  {:>6.2} s  peak RSS {:>7.1} MiB (estimate {:.0} MiB, bound {:.0} MiB, {} banded levels)  \
         {} nodes: {} data / {} uniform / {} empty  volume/file {:.2}x, lz4 {:.2}x",
        mvox_s,
        r.seconds,
        rss,
        r.buffer_estimate as f64 / (1 << 20) as f64,
        opts.memory_bound as f64 / (1 << 20) as f64,
        r.banded_levels,
        r.nodes,
        r.data_nodes,
        r.uniform_nodes,
        r.empty_nodes,
        ratio,
        r.raw_payload_bytes as f64 / r.payload_bytes.max(1) as f64,
    );
    Ok(Built {
        mvox_s,
        rss_mb: rss,
        ratio,
        store: out.to_owned(),
    })
}

/// Decode speed of every data brick of `stores`, single thread, GB/s of output.
fn decode_speed(stores: &[PathBuf]) -> Result<f64, String> {
    let mut payloads = Vec::new();
    for p in stores {
        let s = Store::open(p).map_err(|e| e.to_string())?;
        let bb = s.layout().brick_bytes();
        for rec in s.nodes().filter(|n| n.info.kind == NodeKind::Data) {
            if let Some(c) = s.read_compressed(rec.key).map_err(|e| e.to_string())? {
                payloads.push((c, bb, rec.key));
            }
        }
    }
    let mut out = vec![0u8; payloads.iter().map(|p| p.1).max().unwrap_or(0)];
    let mut bytes = 0u64;
    let t = Instant::now();
    while t.elapsed().as_secs_f64() < 1.5 {
        for (c, bb, key) in &payloads {
            brickray_store::decode_payload(*key, c, &mut out[..*bb]).map_err(|e| e.to_string())?;
            bytes += *bb as u64;
        }
    }
    Ok(bytes as f64 / t.elapsed().as_secs_f64() / 1e9)
}

/// Random leaf brick reads (pread + crc + lz4), single thread: (mean, p50, p99) in µs.
fn read_latency(store: &Path, n: usize) -> Result<(f64, f64, f64), String> {
    let s = Store::open(store).map_err(|e| e.to_string())?;
    let leaf = s.levels() - 1;
    let keys: Vec<NodeKey> = s
        .nodes()
        .filter(|r| r.key.level == leaf && r.info.kind == NodeKind::Data)
        .map(|r| r.key)
        .collect();
    if keys.is_empty() {
        return Err("no data leaves".into());
    }
    let mut buf = vec![0u8; s.layout().brick_bytes()];
    let mut h = 0x9E37_79B9_7F4A_7C15u64;
    let mut times = Vec::with_capacity(n);
    for _ in 0..n {
        h = mix(h.wrapping_add(1));
        let k = keys[(h % keys.len() as u64) as usize];
        let t = Instant::now();
        s.read_brick(k, &mut buf).map_err(|e| e.to_string())?;
        times.push(t.elapsed().as_secs_f64() * 1e6);
    }
    let mean = times.iter().sum::<f64>() / n as f64;
    times.sort_by(f64::total_cmp);
    Ok((mean, times[n / 2], times[n * 99 / 100]))
}

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Smaller inputs, for a quick look.
    #[arg(long)]
    quick: bool,
    /// Keep the stores built.
    #[arg(long)]
    keep: bool,
    /// Inputs 16x smaller per side, for a check that the suite runs (its
    /// figures are not results).
    #[arg(long)]
    smoke: bool,
}

/// One store built.
#[derive(Debug, Serialize)]
pub(crate) struct BuildRow {
    /// What was built: `u8`, `u8_noise`, `u16`, `u8_4gib`,
    /// `u8_4gib_bound128` (generated) or a shared volume's name.
    input: String,
    /// Voxels per side of a generated input (null for shared volumes).
    dims: Option<[u32; 3]>,
    /// The builder's memory bound, MiB.
    memory_bound_mb: u64,
    /// Input voxels per second, millions (best of three for the head CT).
    mvoxel_per_s: f64,
    /// The process's peak RSS over the build, MiB.
    peak_rss_mb: f64,
    /// Input bytes over store bytes.
    ratio: f64,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct BuildResult {
    /// Generated inputs were this many times smaller per side (16 with
    /// `--smoke`, else 1).
    scale: u32,
    rows: Vec<BuildRow>,
    /// Single-thread LZ4 decode of data bricks, GB/s of decoded bytes.
    decode_gb_per_s: f64,
    /// Random leaf reads of the u8 store (warm page cache), µs.
    read_latency_us_mean: f64,
    read_latency_us_p50: f64,
    read_latency_us_p99: f64,
}

pub(crate) fn run(args: &Args) -> Result<BuildResult, String> {
    let smoke = args.smoke;
    let quick = args.quick && !smoke;
    let keep = args.keep;
    // Sides of the generated inputs: 1024 (the u16 input 540 deep, the large
    // one 2048x2048x1024 under a 128 MiB bound), or all 16x smaller.
    let scale = if smoke { 16 } else { 1 };
    let side = 1024 / scale;
    let large = [2048 / scale, 2048 / scale, 1024 / scale];
    let tight_bound: u64 = if smoke { 1 << 20 } else { 128 << 20 };
    let mut rows = Vec::new();
    let mut row = |input: &str, dims: Option<[u32; 3]>, opts: &BuildOptions, b: &Built| {
        rows.push(BuildRow {
            input: input.to_string(),
            dims,
            memory_bound_mb: opts.memory_bound >> 20,
            mvoxel_per_s: round(b.mvox_s, 1),
            peak_rss_mb: round(b.rss_mb, 1),
            ratio: round(b.ratio, 2),
        })
    };
    let tmp = tempfile::Builder::new()
        .prefix("brickray-bench-build-")
        .tempdir()
        .map_err(|e| e.to_string())?;
    let dir = tmp.path().to_owned();
    println!(
        "build suite: {} rayon threads, temp dir {}",
        rayon::current_num_threads(),
        dir.display()
    );
    let opts = BuildOptions::default();

    // 1024^3 u8.
    let input = generate(&dir, "gen_u8_1024", [side; 3], false, false)?;
    let u8_1024 = build_one(
        &input,
        &dir.join("u8_1024.brick"),
        &opts,
        &format!("generated {side}^3 u8"),
    )?;
    let _ = std::fs::remove_file(input.with_extension("raw"));
    row("u8", Some([side; 3]), &opts, &u8_1024);

    // 1024^3 u8 white noise: the worst case (no uniform bricks, incompressible).
    let input = generate(&dir, "gen_u8_1024_noise", [side; 3], false, true)?;
    let noise = build_one(
        &input,
        &dir.join("noise.brick"),
        &opts,
        &format!("generated {side}^3 u8 noise"),
    )?;
    let _ = std::fs::remove_file(input.with_extension("raw"));
    let _ = std::fs::remove_file(&noise.store);
    row("u8_noise", Some([side; 3]), &opts, &noise);

    // 1024x1024x540 u16.
    let input = generate(
        &dir,
        "gen_u16_1024x1024x540",
        [side, side, 540 / scale],
        true,
        false,
    )?;
    let u16b = build_one(
        &input,
        &dir.join("u16.brick"),
        &opts,
        &format!("generated {side}x{side}x{} u16", 540 / scale),
    )?;
    let _ = std::fs::remove_file(input.with_extension("raw"));
    let _ = std::fs::remove_file(&u16b.store);
    row("u16", Some([side, side, 540 / scale]), &opts, &u16b);

    // Shared data: compression ratio per dataset, head CT throughput.
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let mut real = Vec::new();
    for name in [
        "invesalius_cranium_ct",
        "pycortex_s1_t1_mri",
        "cells3d_nuclei_fluo",
        "cryoet_tomo",
    ] {
        let json = data.join(name).join(format!("{name}.json"));
        if !json.exists() {
            println!("  {name}: not found at {}, skipped", json.display());
            continue;
        }
        let out = dir.join(format!("{name}.brick"));
        let mut best: Option<Built> = None;
        for _ in 0..if name == "invesalius_cranium_ct" {
            3
        } else {
            1
        } {
            let b = build_one(&json, &out, &opts, name)?;
            if best.as_ref().is_none_or(|x| b.mvox_s > x.mvox_s) {
                best = Some(b);
            }
        }
        if let Some(b) = best {
            row(name, None, &opts, &b);
            real.push(b.store);
        }
    }
    let decode_gb_per_s = if !real.is_empty() {
        let gbs = decode_speed(&real)?;
        println!(
            "lz4 decode {:.2} GB/s (single thread, decoded bytes, data bricks of {} real stores)",
            gbs,
            real.len()
        );
        round(gbs, 2)
    } else {
        let gbs = decode_speed(std::slice::from_ref(&u8_1024.store))?;
        println!("lz4 decode {gbs:.2} GB/s (generated store; shared data missing)");
        round(gbs, 2)
    };
    let (mean, p50, p99) = read_latency(&u8_1024.store, if smoke { 400 } else { 4000 })?;
    println!(
        "random leaf read ({side}^3 u8 store, warm page cache): mean {mean:.1} µs, p50 {p50:.1} µs, p99 {p99:.1} µs"
    );
    let _ = std::fs::remove_file(&u8_1024.store);

    // 4 GiB input under the default 1 GiB bound.
    if !quick {
        let input = generate(&dir, "gen_u8_2048x2048x1024", large, false, false)?;
        let big = build_one(
            &input,
            &dir.join("big.brick"),
            &opts,
            &format!("generated {}^2x{} u8", large[0], large[2]),
        )?;
        let _ = std::fs::remove_file(&big.store);
        // The same input under a 128 MiB bound: the finest level is built in
        // y-bands (several passes), the rest from a temporary level file.
        let tight = BuildOptions {
            memory_bound: tight_bound,
            ..opts.clone()
        };
        let small = build_one(
            &input,
            &dir.join("big_tight.brick"),
            &tight,
            &format!("same, {} MiB memory bound", tight_bound >> 20),
        )?;
        let _ = std::fs::remove_file(input.with_extension("raw"));
        let _ = std::fs::remove_file(&small.store);
        row("u8_4gib", Some(large), &opts, &big);
        row("u8_4gib_bound128", Some(large), &tight, &small);
    }
    if keep {
        let kept = tmp.keep();
        println!("kept {}", kept.display());
    }
    Ok(BuildResult {
        scale,
        rows,
        decode_gb_per_s,
        read_latency_us_mean: round(mean, 1),
        read_latency_us_p50: round(p50, 1),
        read_latency_us_p99: round(p99, 1),
    })
}

fn round(v: f64, digits: i32) -> f64 {
    let p = 10f64.powi(digits);
    (v * p).round() / p
}
