//! Per-frame upload budget (after Bevy's render-asset budget): a byte allowance per
//! frame that always lets the first item through, so progress is guaranteed even
//! when one item alone exceeds the allowance; what does not fit waits for the next
//! frame.

use brickray_core::NodeKey;

/// Bytes that may be uploaded in one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UploadBudget {
    per_frame: u64,
    used: u64,
    items: u32,
}

impl UploadBudget {
    /// A budget of `bytes_per_frame` (0 = one item per frame).
    pub fn new(bytes_per_frame: u64) -> UploadBudget {
        UploadBudget {
            per_frame: bytes_per_frame,
            used: 0,
            items: 0,
        }
    }

    /// Starts a new frame: nothing used yet.
    pub fn begin_frame(&mut self) {
        self.used = 0;
        self.items = 0;
    }

    /// Reserves `bytes` for one item if they fit in what is left this frame, or if
    /// nothing was reserved yet this frame (progress). Returns whether it did.
    pub fn try_reserve(&mut self, bytes: u64) -> bool {
        self.try_exchange(0, bytes)
    }

    /// Like [`try_reserve`](Self::try_reserve), but also gives back `release` bytes
    /// reserved earlier this frame for an item no longer needed, if it succeeds.
    /// An item larger than the whole allowance goes when nothing is held (first
    /// of the frame, or everything reserved before was given back).
    pub fn try_exchange(&mut self, release: u64, bytes: u64) -> bool {
        let used = self.used.saturating_sub(release);
        if self.items == 0 || used == 0 || used.saturating_add(bytes) <= self.per_frame {
            self.used = used.saturating_add(bytes);
            self.items += 1;
            true
        } else {
            false
        }
    }

    /// Gives back `bytes` reserved earlier this frame.
    pub fn release(&mut self, bytes: u64) {
        self.used = self.used.saturating_sub(bytes);
    }

    /// Bytes reserved this frame.
    pub fn used(&self) -> u64 {
        self.used
    }

    /// Items reserved this frame.
    pub fn items(&self) -> u32 {
        self.items
    }

    /// The per-frame allowance.
    pub fn per_frame(&self) -> u64 {
        self.per_frame
    }

    /// Splits candidates into those uploaded this frame and those deferred: highest
    /// priority first (ties by key for determinism), each taken if it fits; the
    /// first is always taken. Starts a new frame first.
    pub fn select(
        &mut self,
        mut candidates: Vec<UploadCandidate>,
    ) -> (Vec<UploadCandidate>, Vec<UploadCandidate>) {
        self.begin_frame();
        candidates.sort_by(|a, b| b.priority.total_cmp(&a.priority).then(a.key.cmp(&b.key)));
        let mut take = Vec::new();
        let mut defer = Vec::new();
        for c in candidates {
            if self.try_reserve(c.bytes) {
                take.push(c);
            } else {
                defer.push(c);
            }
        }
        (take, defer)
    }
}

/// A brick in CPU memory that is wanted on the GPU.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UploadCandidate {
    /// The node.
    pub key: NodeKey,
    /// Higher goes first.
    pub priority: f32,
    /// Bytes to upload.
    pub bytes: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(i: u32, priority: f32, bytes: u64) -> UploadCandidate {
        UploadCandidate {
            key: NodeKey::new(4, i, 0, 0),
            priority,
            bytes,
        }
    }

    #[test]
    fn picks_highest_priority_within_budget() {
        let mut b = UploadBudget::new(250);
        let (take, defer) = b.select(vec![
            c(0, 1.0, 100),
            c(1, 3.0, 100),
            c(2, 2.0, 100),
            c(3, 0.5, 40),
        ]);
        assert_eq!(
            take.iter().map(|x| x.key.x).collect::<Vec<_>>(),
            vec![1, 2, 3]
        );
        assert_eq!(defer.iter().map(|x| x.key.x).collect::<Vec<_>>(), vec![0]);
        assert_eq!(b.used(), 240);
        // Next frame the deferred one goes.
        let (take, defer) = b.select(defer);
        assert_eq!(take.len(), 1);
        assert!(defer.is_empty());
    }

    #[test]
    fn exchange_releases_on_success_only() {
        let mut b = UploadBudget::new(100);
        assert!(b.try_reserve(80));
        assert!(!b.try_exchange(10, 40));
        assert_eq!(b.used(), 80);
        assert!(b.try_exchange(30, 40));
        assert_eq!(b.used(), 90);
        b.release(50);
        assert_eq!(b.used(), 40);
    }

    #[test]
    fn always_makes_progress() {
        let mut b = UploadBudget::new(10);
        let (take, defer) = b.select(vec![c(0, 1.0, 1000), c(1, 2.0, 1000)]);
        assert_eq!(take.len(), 1);
        assert_eq!(take[0].key.x, 1);
        assert_eq!(defer.len(), 1);
        let mut zero = UploadBudget::new(0);
        let mut pending = vec![c(0, 1.0, 5), c(1, 1.0, 5), c(2, 1.0, 5)];
        let mut frames = 0;
        while !pending.is_empty() {
            let (take, defer) = zero.select(pending);
            assert_eq!(take.len(), 1);
            pending = defer;
            frames += 1;
        }
        assert_eq!(frames, 3);
    }
}
