//! The screen-tile scheduler of occlusion queries (Gobbetti et al. 2008,
//! section 6, Fig. 6).
//!
//! The projected rectangles of the cut's data leaves are split recursively at
//! the median of their centres along alternating axes, building a loose 2D
//! tree: a rectangle that straddles a split stays at that tree node, the others
//! go down to the half that holds them, until a node holds at most the query
//! budget or its tile is too small to split. Each tree node's own rectangles,
//! in chunks of the budget, are one frame's queried subset; frames rotate over
//! the chunks, so every on-screen leaf is queried once every
//! [`TileSchedule::period`] frames (for a fixed set of rectangles). The frame's
//! tiles are the chosen node's tile, first (its rectangles lie inside it), and
//! the sibling tiles along the path to the root: together they partition the
//! viewport.

/// A rectangle of pixels, half-open: `[x0, x1) x [y0, y1)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PxRect {
    /// First column.
    pub x0: u32,
    /// First row.
    pub y0: u32,
    /// One past the last column.
    pub x1: u32,
    /// One past the last row.
    pub y1: u32,
}

impl PxRect {
    /// A rectangle (empty when `x1 <= x0` or `y1 <= y0`).
    pub fn new(x0: u32, y0: u32, x1: u32, y1: u32) -> PxRect {
        PxRect { x0, y0, x1, y1 }
    }

    /// Pixels covered.
    pub fn area(&self) -> u64 {
        self.x1.saturating_sub(self.x0) as u64 * self.y1.saturating_sub(self.y0) as u64
    }

    /// True when it covers no pixel.
    pub fn is_empty(&self) -> bool {
        self.area() == 0
    }

    /// True when `other` lies inside this rectangle.
    pub fn contains(&self, other: &PxRect) -> bool {
        other.x0 >= self.x0 && other.x1 <= self.x1 && other.y0 >= self.y0 && other.y1 <= self.y1
    }

    /// The intersection (possibly empty).
    pub fn intersect(&self, o: &PxRect) -> PxRect {
        PxRect {
            x0: self.x0.max(o.x0),
            y0: self.y0.max(o.y0),
            x1: self.x1.min(o.x1),
            y1: self.y1.min(o.y1),
        }
    }

    fn lo(&self, axis: usize) -> u32 {
        if axis == 0 { self.x0 } else { self.y0 }
    }

    fn hi(&self, axis: usize) -> u32 {
        if axis == 0 { self.x1 } else { self.y1 }
    }

    fn split(&self, axis: usize, at: u32) -> (PxRect, PxRect) {
        let (mut a, mut b) = (*self, *self);
        if axis == 0 {
            a.x1 = at;
            b.x0 = at;
        } else {
            a.y1 = at;
            b.y0 = at;
        }
        (a, b)
    }
}

/// The knobs of [`schedule_tiles`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileSchedulerConfig {
    /// Most occlusion queries per frame (at least 1).
    pub queries_per_frame: usize,
    /// A tile is split only if both halves are at least this many pixels wide
    /// (along the split axis).
    pub min_tile_px: u32,
}

impl Default for TileSchedulerConfig {
    fn default() -> Self {
        TileSchedulerConfig {
            queries_per_frame: 256,
            min_tile_px: 16,
        }
    }
}

/// One frame's schedule.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TileSchedule {
    /// Tiles partitioning the viewport, in the order to ray cast them: the
    /// first holds every queried rectangle (its queries are issued right
    /// after it is cast).
    pub tiles: Vec<PxRect>,
    /// Indices (into the rectangles given) of the leaves to query this frame.
    pub queried: Vec<usize>,
    /// Frames after which the rotation repeats: every on-screen rectangle is
    /// queried once in any `period` consecutive frames (for a fixed set).
    pub period: usize,
    /// Indices of rectangles with no pixel in the viewport (never queried).
    pub offscreen: Vec<usize>,
}

/// A node of the loose median-split tree.
#[derive(Debug)]
struct Node {
    tile: PxRect,
    own: Vec<usize>,
    children: Option<Box<[Node; 2]>>,
}

fn build(
    tile: PxRect,
    mut items: Vec<usize>,
    rects: &[PxRect],
    depth: usize,
    cfg: &TileSchedulerConfig,
) -> Node {
    let budget = cfg.queries_per_frame.max(1);
    let min = cfg.min_tile_px.max(1);
    if items.len() <= budget {
        return Node {
            tile,
            own: items,
            children: None,
        };
    }
    // Alternating axes; the other one when the tile is too narrow for this one.
    for axis in [depth % 2, 1 - depth % 2] {
        let (lo, hi) = (tile.lo(axis), tile.hi(axis));
        if hi.saturating_sub(lo) < 2 * min {
            continue;
        }
        // Sorted by centre (twice the centre, exact in integers); the split
        // goes at the near edge of the median rectangle, so that a set of
        // abutting rectangles splits without straddlers.
        items.sort_by_key(|&i| rects[i].lo(axis) as u64 + rects[i].hi(axis) as u64);
        let at = rects[items[items.len() / 2]]
            .lo(axis)
            .clamp(lo + min, hi - min);
        let (a, b) = tile.split(axis, at);
        let (mut left, mut right, mut own) = (Vec::new(), Vec::new(), Vec::new());
        for &i in &items {
            if rects[i].hi(axis) <= at {
                left.push(i);
            } else if rects[i].lo(axis) >= at {
                right.push(i);
            } else {
                own.push(i);
            }
        }
        if left.is_empty() && right.is_empty() {
            // Everything straddles: splitting isolates nothing.
            continue;
        }
        return Node {
            tile,
            own,
            children: Some(Box::new([
                build(a, left, rects, depth + 1, cfg),
                build(b, right, rects, depth + 1, cfg),
            ])),
        };
    }
    Node {
        tile,
        own: items,
        children: None,
    }
}

/// A frame's choice: a tree node (by its path) and one chunk of its own set.
struct Job {
    path: Vec<u8>,
    chunk: usize,
}

fn jobs(node: &Node, path: &mut Vec<u8>, budget: usize, out: &mut Vec<Job>) {
    for chunk in 0..node.own.len().div_ceil(budget) {
        out.push(Job {
            path: path.clone(),
            chunk,
        });
    }
    if let Some(c) = &node.children {
        for (i, child) in c.iter().enumerate() {
            path.push(i as u8);
            jobs(child, path, budget, out);
            path.pop();
        }
    }
}

/// Schedules frame `frame`'s occlusion queries over `rects` (the projected
/// bounds of the cut's data leaves, in pixels) in `viewport`. Deterministic:
/// the same rectangles and frame give the same schedule.
pub fn schedule_tiles(
    viewport: PxRect,
    rects: &[PxRect],
    cfg: &TileSchedulerConfig,
    frame: u64,
) -> TileSchedule {
    let budget = cfg.queries_per_frame.max(1);
    let clipped: Vec<PxRect> = rects.iter().map(|r| r.intersect(&viewport)).collect();
    let (on, offscreen): (Vec<usize>, Vec<usize>) =
        (0..rects.len()).partition(|&i| !clipped[i].is_empty());
    let root = build(viewport, on, &clipped, 0, cfg);
    let mut list = Vec::new();
    jobs(&root, &mut Vec::new(), budget, &mut list);
    let period = list.len().max(1);
    let mut tiles = Vec::new();
    let mut queried = Vec::new();
    if let Some(job) = list.get((frame % period as u64) as usize) {
        let mut node = &root;
        let mut siblings = Vec::new();
        for &step in &job.path {
            let c = node
                .children
                .as_ref()
                .expect("a job's path follows the tree");
            siblings.push(c[1 - step as usize].tile);
            node = &c[step as usize];
        }
        tiles.push(node.tile);
        // Nearest siblings first: the tiles around the queried one.
        tiles.extend(siblings.into_iter().rev());
        let start = job.chunk * budget;
        queried.extend_from_slice(&node.own[start..(start + budget).min(node.own.len())]);
    } else {
        tiles.push(viewport);
    }
    tiles.retain(|t| !t.is_empty());
    TileSchedule {
        tiles,
        queried,
        period,
        offscreen,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn rect_strategy(w: u32, h: u32) -> impl Strategy<Value = PxRect> {
        (0..w + 40, 0..h + 40, 1u32..w, 1u32..h).prop_map(move |(x, y, rw, rh)| {
            // Some rectangles start left of or above the viewport (clipped).
            let x0 = x.saturating_sub(20);
            let y0 = y.saturating_sub(20);
            PxRect::new(x0, y0, x0 + rw / 4 + 1, y0 + rh / 4 + 1)
        })
    }

    #[test]
    fn few_rectangles_one_tile_every_frame() {
        let vp = PxRect::new(0, 0, 64, 64);
        let rects = [PxRect::new(0, 0, 10, 10), PxRect::new(30, 30, 64, 64)];
        let s = schedule_tiles(vp, &rects, &TileSchedulerConfig::default(), 7);
        assert_eq!(s.tiles, vec![vp]);
        assert_eq!(s.queried, vec![0, 1]);
        assert_eq!(s.period, 1);
    }

    #[test]
    fn splits_isolate_a_subset_in_a_smaller_tile() {
        let vp = PxRect::new(0, 0, 256, 256);
        // A 16 x 16 grid of 16-pixel rectangles, 32 queries a frame.
        let rects: Vec<PxRect> = (0..256)
            .map(|i| {
                let (x, y) = ((i % 16) * 16, (i / 16) * 16);
                PxRect::new(x, y, x + 16, y + 16)
            })
            .collect();
        let cfg = TileSchedulerConfig {
            queries_per_frame: 32,
            min_tile_px: 8,
        };
        let s = schedule_tiles(vp, &rects, &cfg, 0);
        assert!(s.tiles.len() > 1);
        assert!(s.tiles[0].area() < vp.area() / 4, "{:?}", s.tiles[0]);
        assert!(!s.queried.is_empty() && s.queried.len() <= 32);
        // Median splits of a regular grid leave no straddlers: 8 frames of 32.
        assert_eq!(s.period, 8);
    }

    proptest! {
        #[test]
        fn tiles_partition_queried_inside_and_everything_covered_within_the_period(
            w in 16u32..300,
            h in 16u32..300,
            seed_rects in proptest::collection::vec(rect_strategy(300, 300), 0..400),
            budget in 1usize..64,
            min_tile in 1u32..32,
            start in 0u64..1000,
        ) {
            let vp = PxRect::new(0, 0, w, h);
            let cfg = TileSchedulerConfig { queries_per_frame: budget, min_tile_px: min_tile };
            let rects = seed_rects;
            let first = schedule_tiles(vp, &rects, &cfg, start);
            let period = first.period;
            let mut seen = vec![0u32; rects.len()];
            for f in start..start + period as u64 {
                let s = schedule_tiles(vp, &rects, &cfg, f);
                prop_assert_eq!(s.period, period);
                // Tiles partition the viewport: inside it, pairwise disjoint,
                // areas summing to it.
                let mut area = 0u64;
                for (i, t) in s.tiles.iter().enumerate() {
                    prop_assert!(vp.contains(t));
                    area += t.area();
                    for u in &s.tiles[i + 1..] {
                        prop_assert!(t.intersect(u).is_empty(), "{:?} {:?}", t, u);
                    }
                }
                prop_assert_eq!(area, vp.area());
                // The budget holds; each queried rectangle (clipped) lies in
                // the first tile.
                prop_assert!(s.queried.len() <= budget);
                for &i in &s.queried {
                    prop_assert!(s.tiles[0].contains(&rects[i].intersect(&vp)));
                    seen[i] += 1;
                }
            }
            // Every on-screen rectangle exactly once within the period.
            for (i, r) in rects.iter().enumerate() {
                let on = !r.intersect(&vp).is_empty();
                prop_assert_eq!(seen[i], on as u32, "rect {} {:?}", i, r);
            }
        }
    }
}
