//! Reading a region of a level: the decoded units (chunks, or a sharded
//! array's inner chunks) it needs, fetched and decoded concurrently, each
//! once, through the decoded-chunk cache.

use super::*;

impl OmeZarr {
    /// Samples (little-endian, the file's type) of the box `lo..hi` (x, y, z;
    /// exclusive) of `level`, at channel `c` and time `t`: x fastest.
    pub(super) fn region(
        &self,
        level: usize,
        c: u64,
        t: u64,
        lo: [u64; 3],
        hi: [u64; 3],
    ) -> Result<Vec<u8>, IoError> {
        let l = &self.levels[level];
        let mut ranges = vec![0..1; l.shape.len()];
        for a in 0..3 {
            if let Some(i) = self.ax[a] {
                ranges[i] = lo[a]..hi[a];
            }
        }
        if let Some(i) = self.ax[3] {
            ranges[i] = c..c + 1;
        }
        if let Some(i) = self.ax[4] {
            ranges[i] = t..t + 1;
        }
        let sz = self.src.size();
        let n = ranges.len();
        let dims: Vec<u64> = ranges
            .iter()
            .map(|r| r.end.saturating_sub(r.start))
            .collect();
        let total = dims
            .iter()
            .try_fold(sz as u64, |a, &d| a.checked_mul(d))
            .and_then(|b| usize::try_from(b).ok())
            .ok_or_else(|| zerr(&self.root.join(&l.path), "a region too large to read"))?;
        let mut out = vec![0u8; total];
        if total == 0 {
            return Ok(out);
        }
        // The chunks (inner chunks of a sharded array) the region touches,
        // in index order.
        let ulo: Vec<u64> = (0..n).map(|i| ranges[i].start / l.unit[i]).collect();
        let uhi: Vec<u64> = (0..n)
            .map(|i| (ranges[i].end - 1) / l.unit[i] + 1)
            .collect();
        let mut units = Vec::new();
        let mut u = ulo.clone();
        'all: loop {
            units.push(u.clone());
            let mut a = n;
            loop {
                if a == 0 {
                    break 'all;
                }
                a -= 1;
                u[a] += 1;
                if u[a] < uhi[a] {
                    break;
                }
                u[a] = ulo[a];
            }
        }
        let data = self.units(level, &units)?;
        // Output strides (x, the last axis, fastest).
        let mut ostride = vec![sz as u64; n];
        for i in (0..n.saturating_sub(1)).rev() {
            ostride[i] = ostride[i + 1] * dims[i + 1];
        }
        for (u, d) in units.iter().zip(&data) {
            let blo: Vec<u64> = (0..n).map(|i| u[i] * l.unit[i]).collect();
            let bhi: Vec<u64> = (0..n)
                .map(|i| (blo[i] + l.unit[i]).min(l.shape[i]))
                .collect();
            let mut ustride = vec![sz as u64; n];
            for i in (0..n.saturating_sub(1)).rev() {
                ustride[i] = ustride[i + 1] * (bhi[i + 1] - blo[i + 1]);
            }
            let ilo: Vec<u64> = (0..n).map(|i| ranges[i].start.max(blo[i])).collect();
            let ihi: Vec<u64> = (0..n).map(|i| ranges[i].end.min(bhi[i])).collect();
            let run = ((ihi[n - 1] - ilo[n - 1]) * sz as u64) as usize;
            let mut idx = ilo.clone();
            'rows: loop {
                let (mut so, mut dst) = (0u64, 0u64);
                for i in 0..n {
                    so += (idx[i] - blo[i]) * ustride[i];
                    dst += (idx[i] - ranges[i].start) * ostride[i];
                }
                let (so, dst) = (so as usize, dst as usize);
                let src = d.get(so..so + run).ok_or_else(|| {
                    zerr(
                        &self.root.join(&l.path),
                        format!("chunk {u:?} decoded to {} bytes", d.len()),
                    )
                })?;
                out[dst..dst + run].copy_from_slice(src);
                // next row: every axis but the last
                let mut a = n - 1;
                loop {
                    if a == 0 {
                        break 'rows;
                    }
                    a -= 1;
                    idx[a] += 1;
                    if idx[a] < ihi[a] {
                        break;
                    }
                    idx[a] = ilo[a];
                }
            }
        }
        Ok(out)
    }

    /// The decoded samples (little-endian) of each unit (chunk, or a
    /// sharded array's inner chunk) of `level`, clipped to the array: from
    /// the cache, else decoded (several at once, on up to 8 threads, so that
    /// a remote image's round trips overlap; a unit another thread is
    /// decoding is waited for, not fetched twice) and kept.
    pub(super) fn units(
        &self,
        level: usize,
        units: &[Vec<u64>],
    ) -> Result<Vec<Arc<Vec<u8>>>, IoError> {
        let mut out: Vec<Option<Arc<Vec<u8>>>> = units
            .iter()
            .map(|u| self.cache.held(&(level, u.clone())))
            .collect();
        let missing: Vec<usize> = (0..units.len()).filter(|&i| out[i].is_none()).collect();
        let load = |i: usize| -> Result<Arc<Vec<u8>>, IoError> {
            self.cache.get_or_load(&(level, units[i].clone()), || {
                self.unit(level, &units[i]).map(Arc::new)
            })
        };
        if missing.len() <= 1 {
            for &i in &missing {
                out[i] = Some(load(i)?);
            }
        } else {
            let threads = missing.len().min(8);
            let next = std::sync::atomic::AtomicUsize::new(0);
            // The caller's cancel token goes on to the threads that fetch.
            let cancel = brickray_core::CancelToken::current();
            let load = |i: usize| match &cancel {
                Some(c) => c.scope(|| load(i)),
                None => load(i),
            };
            type Loaded = (usize, Result<Arc<Vec<u8>>, IoError>);
            let results: Vec<Vec<Loaded>> = std::thread::scope(|sc| {
                let workers: Vec<_> = (0..threads)
                    .map(|_| {
                        sc.spawn(|| {
                            let mut got = Vec::new();
                            loop {
                                let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                                let Some(&i) = missing.get(k) else { break };
                                let r = load(i);
                                let failed = r.is_err();
                                got.push((i, r));
                                if failed {
                                    break;
                                }
                            }
                            got
                        })
                    })
                    .collect();
                workers
                    .into_iter()
                    .map(|w| {
                        w.join().unwrap_or_else(|_| {
                            vec![(usize::MAX, Err(zerr(&self.root, "a chunk reader panicked")))]
                        })
                    })
                    .collect()
            });
            for (i, r) in results.into_iter().flatten() {
                let v = r?;
                if let Some(slot) = out.get_mut(i) {
                    *slot = Some(v);
                }
            }
        }
        out.into_iter()
            .map(|o| o.ok_or_else(|| zerr(&self.root, "a chunk was not read")))
            .collect()
    }

    /// One unit of `level` (its indices on every axis), clipped to the
    /// array, decoded: samples little-endian, the last axis fastest.
    pub(super) fn unit(&self, level: usize, u: &[u64]) -> Result<Vec<u8>, IoError> {
        let l = &self.levels[level];
        let ranges: Vec<std::ops::Range<u64>> = (0..u.len())
            .map(|i| {
                let lo = u[i] * l.unit[i];
                lo..(lo + l.unit[i]).min(l.shape[i])
            })
            .collect();
        let subset = ArraySubset::new_with_ranges(&ranges);
        let lp = self.root.join(&l.path);
        let _ = self.store.take_error();
        macro_rules! get {
            ($t:ty) => {{
                let v: Vec<$t> = l.array.retrieve_array_subset(&subset).map_err(|e| {
                    // a refused file (a FIFO, a range outside it) or a
                    // remote failure as the typed error it is
                    self.store.take_error().unwrap_or_else(|| zerr(&lp, e))
                })?;
                v.iter().flat_map(|x| x.to_le_bytes()).collect()
            }};
        }
        Ok(match self.src {
            SourceType::U8 => get!(u8),
            SourceType::I8 => get!(i8),
            SourceType::U16 => get!(u16),
            SourceType::I16 => get!(i16),
            SourceType::U32 => get!(u32),
            SourceType::I32 => get!(i32),
            SourceType::F32 => get!(f32),
            SourceType::F64 => get!(f64),
        })
    }

    /// What the decoded-chunk cache holds and has done.
    pub fn chunk_cache_stats(&self) -> ChunkCacheStats {
        self.cache.stats()
    }

    /// Sets the decoded-chunk cache's budget in bytes (default
    /// [`CHUNK_CACHE_BYTES`]; 0 keeps no chunk).
    pub fn set_chunk_cache_budget(&self, bytes: u64) {
        self.cache.set_budget(bytes);
    }
}
