//! What the greedy order ([`super::greedy`]) and the evolving cut
//! ([`super::evolve`]) share when they visit a node that may split: its
//! children classified (or why not), the bricks of its data children, and
//! the requests for what is missing.

use super::rank::{Classified, UNCLASSIFIED, Unknown, classify, known_info};
use super::{
    DataState, LoadRequest, MAX_META_REQUESTS_PER_FRAME, NodeClass, RefineEnv, RefineParams,
    Refinement,
};
use brickray_core::{NodeKey, OctreeLayout};

/// The cut has fewer than this many bricks of room left: a split (which adds
/// up to seven) may not fit, and what a node visited now requests is
/// prefetch for splits the cut cannot take yet.
pub(super) const NEARLY_FULL: u32 = 7;

/// Asks for the metadata of `keys` at `priority`, within the frame's cap.
pub(super) fn request_meta(out: &mut Refinement, keys: &[NodeKey], priority: f64) {
    for &c in keys {
        if out.meta_requests.len() < MAX_META_REQUESTS_PER_FRAME as usize {
            out.meta_requests.push((c, priority as f32));
        }
    }
}

/// The classes of `children` (`children.len()` first entries; with their
/// metadata when `with_info`), or `None` once it is counted in `out` why
/// not: a child whose metadata failed (the node's split is refused, the
/// failed children are needed), or children whose metadata is pending
/// (asked for at `priority`).
pub(super) fn known_children(
    children: &[NodeKey],
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    env: &mut dyn RefineEnv,
    with_info: bool,
    priority: f64,
    out: &mut Refinement,
) -> Option<[Classified; 8]> {
    let mut classes = [UNCLASSIFIED; 8];
    let (mut pending, mut failed) = (Vec::new(), 0u32);
    for (i, &c) in children.iter().enumerate() {
        match classify(c, layout, params, params.views, env, with_info) {
            Ok(cl) => classes[i] = cl,
            Err(Unknown::Pending) => pending.push(c),
            Err(Unknown::Failed) => failed += 1,
        }
    }
    if failed > 0 {
        out.blocked.failed += 1;
        out.failed_needed += failed;
    } else if !pending.is_empty() {
        request_meta(out, &pending, priority);
        out.blocked.missing_meta += 1;
    } else {
        return Some(classes);
    }
    None
}

/// The data children of a split (their indices among the children) and
/// where their bricks are: at most eight, on the stack, as refinement
/// visits tens of thousands of nodes a frame.
pub(super) struct ChildBricks {
    data: [usize; 8],
    states: [DataState; 8],
    n: usize,
}

impl ChildBricks {
    /// The data children among `classes` and their bricks' `state`.
    pub(super) fn of(
        children: &[NodeKey],
        classes: &[Classified; 8],
        mut state: impl FnMut(NodeKey) -> DataState,
    ) -> ChildBricks {
        let mut b = ChildBricks {
            data: [0; 8],
            states: [DataState::Missing; 8],
            n: 0,
        };
        for (i, &c) in children.iter().enumerate() {
            if classes[i].class == NodeClass::Data {
                b.data[b.n] = i;
                b.states[b.n] = state(c);
                b.n += 1;
            }
        }
        b
    }

    /// The data children's indices.
    pub(super) fn data(&self) -> &[usize] {
        &self.data[..self.n]
    }

    /// Where their bricks are, in the order of [`data`](Self::data).
    pub(super) fn states(&self) -> &[DataState] {
        &self.states[..self.n]
    }

    /// How many of their bricks are in `state`.
    pub(super) fn count(&self, state: DataState) -> u32 {
        self.states().iter().filter(|s| **s == state).count() as u32
    }

    /// What a split that waits or does not fit prefetches while the cut is
    /// `nearly_full`: the bricks not on the GPU.
    pub(super) fn prefetch(&self, nearly_full: bool) -> u32 {
        match nearly_full {
            true => self.n as u32 - self.count(DataState::OnGpu),
            false => 0,
        }
    }

    /// Requests the missing bricks at `order` (their metadata from their
    /// classes, or the cache).
    pub(super) fn request_missing(
        &self,
        children: &[NodeKey],
        classes: &[Classified; 8],
        order: f64,
        env: &mut dyn RefineEnv,
        out: &mut Refinement,
    ) {
        for (&i, s) in self.data().iter().zip(self.states()) {
            if *s != DataState::Missing {
                continue;
            }
            let info = match &classes[i].info {
                Some(info) => Some(info.clone()),
                None => known_info(env, children[i]),
            };
            if let Some(info) = info {
                out.requests.push(LoadRequest {
                    key: children[i],
                    priority: order as f32,
                    info,
                });
            }
        }
    }
}
