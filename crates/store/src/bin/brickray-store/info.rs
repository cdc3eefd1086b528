//! `brickray-store info`: what a store, a channel set, an input volume or
//! an OME-Zarr image at a URL holds.

use super::*;

/// `info` of an OME-Zarr image named by a URL (`None`: the name is not a
/// URL, or names a store).
pub(crate) fn info_zarr_url(
    name: &std::path::Path,
    remote: &RemoteArgs,
    read: &brickray_io::ReadOptions,
) -> Option<Result<(), String>> {
    let name = name.to_string_lossy();
    if !looks_like_url(&name) {
        return None;
    }
    #[cfg(feature = "remote")]
    {
        let o = remote_options(remote);
        if !brickray_store::is_zarr_url(&name, &o) {
            return None;
        }
        let d = BuildOptions::default();
        let src = match brickray_store::open_zarr_url(&name, &o, read, d.brick, d.apron) {
            Ok(s) => s,
            Err(e) => return Some(Err(e.to_string())),
        };
        let img = src.image();
        let lay = src.layout();
        let v = &lay.volume;
        println!("image       {name}");
        println!(
            "format      OME-Zarr {}, {} levels, streamed (not a store)",
            img.version(),
            img.level_count()
        );
        println!(
            "volume      {}x{}x{} {}, spacing {:?}, value range {:?}",
            v.dims[0],
            v.dims[1],
            v.dims[2],
            v.dtype.name(),
            v.spacing,
            v.value_range
        );
        println!(
            "bricks      {} interior + 2x{} apron, {} octree levels",
            lay.brick, lay.apron, lay.levels
        );
        for e in img.entries(read) {
            let mark = if e.default { "*" } else { " " };
            println!("{:<11} {mark} {}  {}", e.kind.to_string(), e.id, e.summary);
        }
        for w in src.warnings() {
            println!("warning     {w}");
        }
        Some(Ok(()))
    }
    #[cfg(not(feature = "remote"))]
    {
        let _ = (remote, read);
        None
    }
}

/// `info` of a channel set: each channel's description, then its store's.
pub(crate) fn cmd_info_channels(path: &std::path::Path, bins: usize) -> Result<(), String> {
    let set = brickray_store::open_channels(path).map_err(|e| e.to_string())?;
    println!(
        "channel set {} ({} channels)",
        path.display(),
        set.stores.len()
    );
    for (c, (info, store)) in set.info.iter().zip(&set.stores).enumerate() {
        println!(
            "channel {c}   {} colour {:?} window {:?} {}",
            info.label.as_deref().unwrap_or("(no label)"),
            info.color,
            info.window,
            if info.active { "shown" } else { "hidden" }
        );
        let s = Store::open(store).map_err(|e| e.to_string())?;
        cmd_info(&s, bins)?;
    }
    Ok(())
}

/// The placement's voxel-to-world affine (its first three rows), for `info`
/// on an input and on a store.
fn print_placement(p: &brickray_io::Placement) {
    println!("placement   voxel to world ({}):", p.space);
    for row in &p.affine[..3] {
        println!(
            "              [{:>10.4} {:>10.4} {:>10.4} {:>10.4}]",
            row[0], row[1], row[2], row[3]
        );
    }
}

/// The `volume` line: dims, type (and labels), spacing, value range.
fn print_volume(d: &brickray_core::VolumeDesc) {
    println!(
        "volume      {}x{}x{} {}{}, spacing {:?}, value range {:?}",
        d.dims[0],
        d.dims[1],
        d.dims[2],
        d.dtype.name(),
        if d.kind.is_labels() { " labels" } else { "" },
        d.spacing,
        d.value_range
    );
}

pub(crate) fn cmd_info_input(input: &std::path::Path, read: &ReadOptions) -> Result<(), String> {
    let reader =
        brickray_io::open_with(input, read).map_err(|e| StoreError::Input(e).to_string())?;
    let d = reader.desc();
    println!("input       {} ({})", input.display(), reader.format());
    print_volume(d);
    if let Some(p) = reader.placement() {
        print_placement(&p);
    }
    println!("files       {}", reader.input_files().len());
    for n in reader.notes() {
        println!("note        {n}");
    }
    for w in reader.warnings() {
        println!("warning     {w}");
    }
    let entries = brickray_io::list(input, read).map_err(|e| StoreError::Input(e).to_string())?;
    for e in entries {
        let mark = if e.default { "*" } else { " " };
        println!("{:<11} {mark} {}  {}", e.kind.to_string(), e.id, e.summary);
    }
    Ok(())
}

pub(crate) fn cmd_info(store: &Store, bins: usize) -> Result<(), String> {
    let path = store.path().display();
    let lay = store.layout().clone();
    let d = store.desc();
    println!("store       {path}");
    print_volume(d);
    if let Some(p) = store.placement() {
        print_placement(&p);
    }
    println!("data range  {:?}", store.data_range());
    println!(
        "bricks      {} interior + 2x{} apron = {} stored voxels a side ({} bytes), filter {:?}, empty below {:?}",
        lay.brick,
        lay.apron,
        lay.stored_side(),
        lay.brick_bytes(),
        store.filter(),
        store.empty_below()
    );
    let s = store.stats();
    let total: u64 = s.per_level.iter().map(|l| l[0]).sum();
    println!("levels      {}", lay.levels);
    if !lay.is_isotropic() {
        // Octal digits: 1 x, 2 y, 4 z (7: all axes).
        let m: Vec<String> = lay.split_masks().iter().map(|m| format!("{m:o}")).collect();
        println!(
            "split masks {} (anisotropic pyramid, root first)",
            m.join(",")
        );
    }
    println!("  level   grid            nodes      data   uniform     empty");
    for (l, c) in s.per_level.iter().enumerate() {
        let g = store.grid(l as u8).unwrap_or([0; 3]);
        println!(
            "  {l:>5}   {:<14} {:>6} {:>9} {:>9} {:>9}",
            format!("{}x{}x{}", g[0], g[1], g[2]),
            c[0],
            c[1],
            c[2],
            c[3]
        );
    }
    let frac = |n: u64| 100.0 * n as f64 / total.max(1) as f64;
    println!(
        "nodes       {total}: {:.1}% data, {:.1}% uniform, {:.1}% empty",
        frac(s.data),
        frac(s.uniform),
        frac(s.empty)
    );
    println!(
        "size        {:.2} MiB file, {:.2} MiB payload; volume {:.2} MiB",
        store.file_len() as f64 / (1 << 20) as f64,
        s.payload_bytes as f64 / (1 << 20) as f64,
        d.byte_len() as f64 / (1 << 20) as f64
    );
    if store.has_spread() {
        println!(
            "spreads     recorded (format version {}): {:.2} MiB of spread payload",
            store.version(),
            store.spread_bytes() as f64 / (1 << 20) as f64
        );
    } else {
        println!("spreads     not recorded (build with --spread to record them)");
    }
    println!(
        "compression {:.2}x lz4 on data bricks; {:.2}x volume bytes / file bytes",
        s.raw_payload_bytes as f64 / s.payload_bytes.max(1) as f64,
        d.byte_len() as f64 / store.file_len().max(1) as f64
    );
    // Histogram of the finest level's voxels (leaf interiors inside the volume).
    let leaf = lay.levels - 1;
    let [lo, hi] = store.data_range();
    let span = (hi - lo).max(f32::MIN_POSITIVE);
    let keys: Vec<_> = store.nodes().filter(|n| n.key.level == leaf).collect();
    // Over the network a store reads its bricks in batches (one round trip
    // each); a local file one by one.
    let hist = keys
        .par_chunks(store.batch_size().max(1))
        .map(|chunk| -> Result<Vec<u64>, String> {
            let mut h = vec![0u64; bins];
            let bin = |v: f32| (((v - lo) / span * bins as f32) as usize).min(bins - 1);
            let data: Vec<_> = chunk
                .iter()
                .filter(|r| matches!(r.info.kind, NodeKind::Data))
                .collect();
            let mut bufs = vec![vec![0u8; lay.brick_bytes()]; data.len()];
            let mut outs: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
            let keys: Vec<_> = data.iter().map(|r| r.key).collect();
            for r in store.read_bricks(&keys, &mut outs, &brickray_core::CancelToken::new()) {
                r.map_err(|e| e.to_string())?;
            }
            let mut next = bufs.iter();
            for rec in chunk {
                let b = lay.brick as u64;
                let ext = [rec.key.x, rec.key.y, rec.key.z]
                    .map(|p| p as u64 * b)
                    .iter()
                    .zip(d.dims)
                    .map(|(&o, n)| (n as u64 - o).min(b))
                    .collect::<Vec<_>>();
                let count = ext.iter().product::<u64>();
                match rec.info.kind {
                    NodeKind::Uniform(v) => h[bin(v)] += count,
                    NodeKind::Empty => h[bin(lo)] += count,
                    NodeKind::Data => {
                        let buf = next.next().ok_or("a brick was not read")?;
                        let vals = d.dtype.decode_le(buf);
                        let s = lay.stored_side() as usize;
                        let a = lay.apron as usize;
                        for k in 0..ext[2] as usize {
                            for j in 0..ext[1] as usize {
                                let row = ((k + a) * s + j + a) * s + a;
                                for v in &vals[row..row + ext[0] as usize] {
                                    h[bin(*v)] += 1;
                                }
                            }
                        }
                    }
                }
            }
            Ok(h)
        })
        .try_reduce(
            || vec![0u64; bins],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                Ok(a)
            },
        )?;
    let n: u64 = hist.iter().sum();
    let peak = *hist.iter().max().unwrap_or(&1);
    println!("histogram   {n} voxels, {bins} bins over the data range");
    for (i, c) in hist.iter().enumerate() {
        let a = lo + span * i as f32 / bins as f32;
        let b = lo + span * (i + 1) as f32 / bins as f32;
        let bar = "#".repeat(((*c as f64 / peak.max(1) as f64) * 40.0).round() as usize);
        println!(
            "  [{a:>11.4}, {b:>11.4})  {c:>12}  {:>5.1}%  {bar}",
            100.0 * *c as f64 / n.max(1) as f64
        );
    }
    Ok(())
}
