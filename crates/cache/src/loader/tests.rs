use super::*;
use crate::refine::tests::ball_info;
use crate::test_source::{TestSource, fill_byte, test_gpu};
use std::time::Instant;

fn k(level: u8, x: u32) -> NodeKey {
    NodeKey::new(level, x, 0, 0)
}

fn loader(src: &Arc<TestSource>, workers: usize) -> Loader {
    let prep = Preparer::new(&src.layout, &test_gpu(&src.layout)).unwrap();
    let config = LoaderConfig {
        workers,
        ..LoaderConfig::default()
    };
    Loader::new(src.clone(), Arc::new(prep), config).unwrap()
}

fn brick(src: &TestSource, key: NodeKey, priority: f32) -> BrickRequest {
    BrickRequest {
        key,
        priority,
        info: ball_info(&src.layout, key).into(),
        children_meta: false,
    }
}

fn idle(l: &Loader) -> bool {
    [FetchKind::Metadata, FetchKind::Brick]
        .iter()
        .all(|&kind| l.queued(kind) == 0 && l.loading(kind) == 0)
}

/// Polls until `done` holds, failing after 5 s; returns everything polled.
fn poll_until(
    loader: &mut Loader,
    cache: &mut CpuCache,
    mut done: impl FnMut(&Loader, &CpuCache) -> bool,
) -> PollReport {
    let t = Instant::now();
    let mut all = PollReport::default();
    while !done(loader, cache) {
        let r = loader.poll(cache);
        all.loaded.extend(r.loaded);
        all.metadata.extend(r.metadata);
        all.failed.extend(r.failed);
        all.evicted.extend(r.evicted);
        all.cancelled.extend(r.cancelled);
        assert!(
            t.elapsed() < Duration::from_secs(5),
            "timed out: {loader:?}"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
    all
}

/// Waits (at most 5 s) until no thread but the test holds the source.
fn wait_released(src: &Arc<TestSource>) {
    let t = Instant::now();
    while Arc::strong_count(src) > 1 {
        assert!(
            t.elapsed() < Duration::from_secs(5),
            "a worker kept the source"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn delivers_prepared_bricks_into_cpu_cache() {
    let src = Arc::new(TestSource::new(64));
    let mut loader = loader(&src, 2);
    let mut cache = CpuCache::new(1 << 20);
    let keys: Vec<NodeKey> = (0..4).map(|x| k(2, x)).collect();
    for (i, key) in keys.iter().enumerate() {
        let outcome = loader.request_brick(brick(&src, *key, i as f32));
        assert_eq!(outcome, RequestOutcome::Queued);
    }
    poll_until(&mut loader, &mut cache, |l, c| {
        keys.iter().all(|k| c.contains(*k)) && idle(l)
    });
    for key in &keys {
        let b = cache.peek(*key).unwrap();
        // R16Unorm of u8: `raw * 257`, both bytes equal the raw byte.
        assert_eq!(b.texels.len(), 2 * src.layout.brick_bytes());
        assert!(b.texels.iter().all(|&v| v == fill_byte(*key)));
        let fill = fill_byte(*key) as f32;
        assert_eq!(&*b.sub_cells, &[[fill, fill]]);
        let info = ball_info(&src.layout, *key);
        assert_eq!(b.range, [info.min.min(fill), info.max.max(fill)]);
    }
    assert_eq!(loader.loaded_total(), 4);
    // Bricks were read and prepared without any metadata call.
    assert!(src.calls_of(FetchKind::Metadata).is_empty());
}

#[test]
fn metadata_first_then_bricks_by_priority() {
    let mut src = TestSource::new(64);
    let gate = k(1, 0);
    src.gate_key = Some(gate);
    let src = Arc::new(src);
    let mut loader = loader(&src, 1);
    let mut cache = CpuCache::new(1 << 20);
    loader.request_brick(brick(&src, gate, 100.0));
    poll_until(&mut loader, &mut cache, |l, _| {
        l.is_loading(FetchKind::Brick, gate)
    });
    // The single worker is held by the gate: everything below is ordered.
    for x in 0..6 {
        loader.request_brick(brick(&src, k(3, x), x as f32));
    }
    let again = loader.request_brick(brick(&src, k(3, 0), 10.0));
    assert_eq!(again, RequestOutcome::Reprioritized);
    let loading = loader.request_brick(brick(&src, gate, 1.0));
    assert_eq!(loading, RequestOutcome::Loading);
    // Metadata at a low priority still goes before every brick.
    loader.request_metadata(k(2, 1), -5.0);
    loader.request_metadata(k(2, 0), 0.5);
    assert_eq!(loader.queued(FetchKind::Brick), 6);
    assert_eq!(loader.queued(FetchKind::Metadata), 2);
    src.open_gate();
    let report = poll_until(&mut loader, &mut cache, |l, _| idle(l));
    let order: Vec<(FetchKind, u32)> = src.calls().iter().skip(1).map(|c| (c.0, c.1.x)).collect();
    let b = |x| (FetchKind::Brick, x);
    let m = |x| (FetchKind::Metadata, x);
    assert_eq!(order, vec![m(0), m(1), b(0), b(5), b(4), b(3), b(2), b(1)]);
    let mut meta: Vec<NodeKey> = report.metadata.iter().map(|m| m.0).collect();
    meta.sort();
    assert_eq!(meta, vec![k(2, 0), k(2, 1)]);
    assert_eq!(report.metadata[0].1, ball_info(&src.layout, k(2, 0)));
}

#[test]
fn brick_jobs_read_their_childrens_metadata() {
    let src = Arc::new(TestSource::new(40));
    let mut loader = loader(&src, 1);
    let mut cache = CpuCache::new(1 << 20);
    // 40^3 in bricks of 8: the octree cube is 64 voxels, so of the level-2
    // node (2,2,2,2) (voxels 32..48) only the child at 32..40 lies inside.
    let parent = NodeKey::new(2, 2, 2, 2);
    loader.request_brick(BrickRequest {
        children_meta: true,
        ..brick(&src, parent, 1.0)
    });
    loader.request_brick(brick(&src, NodeKey::ROOT, 0.5));
    let report = poll_until(&mut loader, &mut cache, |l, _| idle(l));
    let inside: Vec<NodeKey> = parent
        .children()
        .into_iter()
        .filter(|c| src.layout.in_volume(*c))
        .collect();
    assert!(!inside.is_empty() && inside.len() < 8);
    let got: Vec<NodeKey> = report.metadata.iter().map(|m| m.0).collect();
    assert_eq!(got, inside);
    for (c, info) in &report.metadata {
        assert_eq!(*info, ball_info(&src.layout, *c));
    }
    assert_eq!(report.loaded.len(), 2);
}

#[test]
fn submit_cancels_what_is_no_longer_wanted() {
    let mut src = TestSource::new(64);
    let gate = k(1, 0);
    src.gate_key = Some(gate);
    let src = Arc::new(src);
    let mut loader = loader(&src, 1);
    let mut cache = CpuCache::new(1 << 20);
    loader.request_brick(brick(&src, gate, 100.0));
    poll_until(&mut loader, &mut cache, |l, _| {
        l.is_loading(FetchKind::Brick, gate)
    });
    let wanted: Vec<BrickRequest> = (0..6).map(|x| brick(&src, k(3, x), 1.0)).collect();
    assert_eq!(loader.submit(&[(k(2, 3), 1.0)], &wanted), 0);
    // Next frame only two bricks are still wanted (one with a new priority), and
    // no metadata.
    let next = [brick(&src, k(3, 4), 1.0), brick(&src, k(3, 1), 5.0)];
    assert_eq!(loader.submit(&[], &next), 5);
    // (The brick being read is not wanted either, but a source without
    // batches cannot abort it.)
    assert_eq!(loader.cancelled(), (5, 0));
    assert!(loader.cancel(FetchKind::Brick, k(3, 4)));
    assert!(!loader.cancel(FetchKind::Brick, k(3, 4)));
    src.open_gate();
    poll_until(&mut loader, &mut cache, |l, _| idle(l));
    assert_eq!(src.reads(), vec![gate, k(3, 1)]);
    assert!(src.calls_of(FetchKind::Metadata).is_empty());
    assert!(cache.contains(k(3, 1)) && !cache.contains(k(3, 4)));
}

#[test]
fn failures_and_panics_are_reported_not_raised() {
    let src = Arc::new(TestSource::new(64));
    src.fail(FetchKind::Brick, k(2, 1));
    src.panic_on(FetchKind::Brick, k(2, 2));
    src.fail(FetchKind::Metadata, k(2, 1));
    src.panic_on(FetchKind::Metadata, k(2, 2));
    let mut loader = loader(&src, 2);
    let mut cache = CpuCache::new(1 << 20);
    let bricks: Vec<BrickRequest> = (0..3).map(|x| brick(&src, k(2, x), 1.0)).collect();
    loader.submit(&[(k(2, 1), 1.0), (k(2, 2), 1.0)], &bricks);
    let report = poll_until(&mut loader, &mut cache, |l, _| idle(l));
    assert!(cache.contains(k(2, 0)));
    let mut failed: Vec<(FetchKind, NodeKey, bool)> = report
        .failed
        .iter()
        .map(|(kind, key, e)| (*kind, *key, matches!(e, LoadError::Panicked { .. })))
        .collect();
    failed.sort();
    assert_eq!(
        failed,
        vec![
            (FetchKind::Metadata, k(2, 1), false),
            (FetchKind::Metadata, k(2, 2), true),
            (FetchKind::Brick, k(2, 1), false),
            (FetchKind::Brick, k(2, 2), true),
        ]
    );
    let io = report.failed.iter().find(|f| f.1 == k(2, 1)).unwrap();
    assert!(matches!(io.2, LoadError::Source(BrickError::Io { .. })));
    // The workers survived the panics.
    loader.request_brick(brick(&src, k(2, 3), 1.0));
    poll_until(&mut loader, &mut cache, |_, c| c.contains(k(2, 3)));
}

#[test]
fn drop_with_loads_in_flight_drops_the_queue() {
    let mut src = TestSource::new(128);
    src.delay = Duration::from_millis(10);
    let src = Arc::new(src);
    let loader = loader(&src, 3);
    let wanted: Vec<BrickRequest> = (0..256)
        .map(|x| brick(&src, NodeKey::new(4, x % 16, x / 16, 0), x as f32))
        .collect();
    loader.submit(&[], &wanted);
    let t = Instant::now();
    while loader.loading(FetchKind::Brick) == 0 {
        assert!(t.elapsed() < Duration::from_secs(5));
        std::thread::yield_now();
    }
    drop(loader);
    // Every thread lets go of the source; only reads already started ran, not
    // the 256 queued.
    wait_released(&src);
    assert!(src.reads().len() < 256);
}

/// A read that never returns (a gate opened only at the end) cannot hold up
/// the drop; the detached thread exits once the read returns.
#[test]
fn drop_returns_while_a_read_or_metadata_call_hangs() {
    for kind in [FetchKind::Brick, FetchKind::Metadata] {
        let mut src = TestSource::new(64);
        let hung = k(1, 0);
        match kind {
            FetchKind::Brick => src.gate_key = Some(hung),
            FetchKind::Metadata => src.meta_gate_key = Some(hung),
        }
        let src = Arc::new(src);
        let mut loader = loader(&src, 2);
        let mut cache = CpuCache::new(1 << 20);
        match kind {
            FetchKind::Brick => loader.request_brick(brick(&src, hung, 1.0)),
            FetchKind::Metadata => loader.request_metadata(hung, 1.0),
        };
        poll_until(&mut loader, &mut cache, |l, _| l.is_loading(kind, hung));
        let t = Instant::now();
        drop(loader);
        // Bounded wait for liveness: the drop waits SHUTDOWN_WAIT, not forever.
        assert!(t.elapsed() < Duration::from_secs(5), "{kind}: drop blocked");
        assert!(Arc::strong_count(&src) > 1, "the hung thread still runs");
        src.open_gate();
        wait_released(&src);
    }
}

/// A source asking for batches of `batch`, whose read of `k(3, 0)` waits
/// for its gate (what it is also told: `setup`).
fn batching(batch: usize, setup: impl FnOnce(&TestSource)) -> Arc<TestSource> {
    let mut src = TestSource::new(64);
    src.batch = batch;
    src.gate_key = Some(k(3, 0));
    setup(&src);
    Arc::new(src)
}

/// Requests `k(3, 0)` at a high priority and waits (at most 5 s) until a
/// thread holds it.
fn hold_first(loader: &Loader, src: &TestSource) {
    loader.request_brick(brick(src, k(3, 0), 100.0));
    let t = Instant::now();
    while loader.loading(FetchKind::Brick) == 0 {
        assert!(t.elapsed() < Duration::from_secs(5));
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn a_batching_source_gets_queued_bricks_together_in_priority_order() {
    // A source over the network asks for batches of 4: one worker, gated on
    // the first brick so that the rest queue behind it.
    let src = batching(4, |s| s.fail(FetchKind::Brick, k(3, 5)));
    let mut loader = loader(&src, 1);
    let mut cache = CpuCache::new(1 << 22);
    hold_first(&loader, &src);
    // Queued while the first is held: priority 1..=9 (the highest first).
    let keys: Vec<NodeKey> = (1..10).map(|x| k(3, x)).collect();
    for (i, key) in keys.iter().enumerate() {
        loader.request_brick(brick(&src, *key, (i + 1) as f32));
    }
    src.open_gate();
    let report = poll_until(&mut loader, &mut cache, |l, _| idle(l));
    let batches = src.batches.lock().clone();
    // The first was taken alone (nothing else was queued); the other nine in
    // batches of 4, 4 and 1, highest priority first.
    assert_eq!(batches[0], vec![k(3, 0)]);
    let rest: Vec<NodeKey> = batches[1..].iter().flatten().copied().collect();
    let by_priority: Vec<NodeKey> = keys.iter().rev().copied().collect();
    assert_eq!(rest, by_priority);
    let sizes: Vec<usize> = batches.iter().map(Vec::len).collect();
    assert_eq!(sizes, [1, 4, 4, 1]);
    // The failing brick failed alone; every other arrived.
    assert_eq!(report.failed.len(), 1);
    assert_eq!(report.failed[0].1, k(3, 5));
    for key in std::iter::once(k(3, 0))
        .chain(keys)
        .filter(|&key| key != k(3, 5))
    {
        assert!(cache.contains(key), "{key:?} missing");
    }
}

#[test]
fn a_panic_in_a_batch_fails_its_bricks_only() {
    let src = batching(8, |s| s.panic_on(FetchKind::Brick, k(3, 2)));
    let mut loader = loader(&src, 1);
    let mut cache = CpuCache::new(1 << 22);
    hold_first(&loader, &src);
    for x in 1..4 {
        loader.request_brick(brick(&src, k(3, x), 1.0));
    }
    src.open_gate();
    let report = poll_until(&mut loader, &mut cache, |l, _| idle(l));
    // The batch of three panicked as a whole: each of its bricks failed,
    // typed; the loader goes on.
    assert_eq!(report.failed.len(), 3, "{:?}", report.failed);
    assert!(
        report
            .failed
            .iter()
            .all(|f| matches!(f.2, LoadError::Panicked { .. }))
    );
    assert!(cache.contains(k(3, 0)));
    loader.request_brick(brick(&src, k(3, 9), 1.0));
    poll_until(&mut loader, &mut cache, |l, c| {
        c.contains(k(3, 9)) && idle(l)
    });
}

#[test]
fn a_batch_the_view_left_is_cancelled_in_flight() {
    // Batches of 4 over a "network" that holds the batch with k(3, 0) until
    // the gate opens or the batch is cancelled.
    let src = batching(4, |_| ());
    let mut loader = loader(&src, 1);
    let mut cache = CpuCache::new(1 << 22);
    let first: Vec<BrickRequest> = (0..3).map(|x| brick(&src, k(3, x), 10.0)).collect();
    loader.submit(&[], &first);
    let t = Instant::now();
    while loader.loading(FetchKind::Brick) < 3 {
        assert!(t.elapsed() < Duration::from_secs(5));
        std::thread::sleep(Duration::from_millis(1));
    }
    // Still wanted in part: the batch goes on.
    loader.submit(&[], &first[1..2]);
    std::thread::sleep(Duration::from_millis(20));
    assert_eq!(loader.cancelled(), (0, 0));
    assert_eq!(loader.loading(FetchKind::Brick), 3);
    // The view moved on: none of its bricks is wanted, a new one is.
    let moved = [brick(&src, k(3, 7), 10.0)];
    loader.submit(&[], &moved);
    let report = poll_until(&mut loader, &mut cache, |l, c| {
        c.contains(k(3, 7)) && idle(l)
    });
    assert_eq!(loader.cancelled(), (0, 3));
    let mut cancelled = report.cancelled.clone();
    cancelled.sort_by_key(|k| k.x);
    assert_eq!(cancelled, vec![k(3, 0), k(3, 1), k(3, 2)]);
    assert!(report.failed.is_empty(), "{:?}", report.failed);
    assert!(!cache.contains(k(3, 0)));
    src.open_gate();
}

#[test]
fn bricks_in_flight_stay_within_the_budget() {
    // Four threads, batches of 4, but room for 3 bricks in flight: the gated
    // first brick holds one; at most two more may be read meanwhile.
    let src = batching(4, |_| ());
    let prep = Preparer::new(&src.layout, &test_gpu(&src.layout)).unwrap();
    let config = LoaderConfig {
        workers: 4,
        max_in_flight: 3,
    };
    let mut loader = Loader::new(src.clone(), Arc::new(prep), config).unwrap();
    let mut cache = CpuCache::new(1 << 22);
    loader.request_brick(brick(&src, k(3, 0), 100.0));
    let t = Instant::now();
    while loader.loading(FetchKind::Brick) == 0 {
        assert!(t.elapsed() < Duration::from_secs(5));
        std::thread::sleep(Duration::from_millis(1));
    }
    let rest: Vec<BrickRequest> = (1..12).map(|x| brick(&src, k(3, x), 1.0)).collect();
    for r in &rest {
        loader.request_brick(r.clone());
    }
    // Metadata is never held back by the budget.
    loader.request_metadata(k(2, 1), 1.0);
    let mut most = 0;
    let t = Instant::now();
    while t.elapsed() < Duration::from_millis(100) {
        most = most.max(loader.loading(FetchKind::Brick));
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(most <= 3, "{most} bricks in flight");
    // (The two others were read; their results wait for a poll.)
    assert_eq!(loader.loading(FetchKind::Brick), 3);
    assert!(src.calls_of(FetchKind::Metadata).contains(&k(2, 1)));
    // Polling makes room; a larger budget lets the rest through.
    loader.set_max_in_flight(8);
    src.open_gate();
    let report = poll_until(&mut loader, &mut cache, |l, c| {
        most = most.max(l.loading(FetchKind::Brick));
        (0..12).all(|x| c.contains(k(3, x))) && idle(l)
    });
    assert!(report.failed.is_empty());
    assert!(most <= 8, "{most}");
}

/// A brick's children's metadata is asked for in one `nodes` call (a source
/// over the network reads them together); a child whose metadata panics or
/// fails fails alone.
#[test]
fn a_bricks_children_are_read_in_one_call_and_fail_alone() {
    let src = TestSource::new(64);
    src.panic_on(FetchKind::Metadata, k(2, 1));
    let failing = NodeKey::new(2, 0, 1, 0);
    src.fail(FetchKind::Metadata, failing);
    let src = Arc::new(src);
    let mut loader = loader(&src, 1);
    let mut cache = CpuCache::new(1 << 22);
    loader.request_brick(BrickRequest {
        children_meta: true,
        ..brick(&src, k(1, 0), 1.0)
    });
    let report = poll_until(&mut loader, &mut cache, |l, _| idle(l));
    let children: Vec<NodeKey> = NodeKey::new(1, 0, 0, 0).children().to_vec();
    assert!(
        src.node_batches.lock().first() == Some(&children),
        "{:?}",
        src.node_batches.lock()
    );
    let failed: Vec<NodeKey> = report.failed.iter().map(|f| f.1).collect();
    assert_eq!(failed.len(), 2, "{:?}", report.failed);
    assert!(failed.contains(&k(2, 1)) && failed.contains(&failing));
    let got: Vec<NodeKey> = report.metadata.iter().map(|m| m.0).collect();
    assert_eq!(got.len(), 6, "{got:?}");
    for c in children.iter().filter(|c| !failed.contains(c)) {
        assert!(got.contains(c), "{c:?}");
        assert_eq!(
            report.metadata.iter().find(|m| m.0 == *c).unwrap().1,
            ball_info(&src.layout, *c)
        );
    }
}

/// A source read in batches gets its queued metadata jobs in batches too,
/// highest priority first, each batch in one `nodes` call.
#[test]
fn a_batching_source_gets_queued_metadata_together() {
    let src = batching(4, |_| {});
    let mut loader = loader(&src, 1);
    let mut cache = CpuCache::new(1 << 22);
    hold_first(&loader, &src);
    let keys: Vec<NodeKey> = (0..8).map(|x| k(3, x)).chain([k(2, 0)]).collect();
    for (i, key) in keys.iter().enumerate() {
        loader.request_metadata(*key, (i + 1) as f32);
    }
    src.open_gate();
    let report = poll_until(&mut loader, &mut cache, |l, _| idle(l));
    let batches = src.node_batches.lock().clone();
    let sizes: Vec<usize> = batches.iter().map(Vec::len).collect();
    assert_eq!(sizes, [4, 4, 1], "{batches:?}");
    let order: Vec<NodeKey> = batches.into_iter().flatten().collect();
    assert_eq!(order, keys.iter().rev().copied().collect::<Vec<_>>());
    assert_eq!(report.metadata.len(), keys.len());
    for (key, info) in &report.metadata {
        assert_eq!(*info, ball_info(&src.layout, *key));
    }
}
