//! The policy switch.

/// Where refinement's visibility comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum VisibilityPolicy {
    /// No feedback: every node in the frustum whose range is not transparent
    /// is refined (the behaviour before visibility feedback).
    #[default]
    None,
    /// Occlusion queries of leaf boxes against the depth of the last visited
    /// sample, scheduled over screen tiles (the paper's method).
    OcclusionQueries,
    /// The ray caster counts, per pool slot, the rays that reached the brick
    /// before terminating (ray-guided usage feedback).
    RayGuided,
    /// Both: a leaf is visible when either source says so.
    Both,
}

impl VisibilityPolicy {
    /// All policies, in the order benches report them.
    pub const ALL: [VisibilityPolicy; 4] = [
        VisibilityPolicy::None,
        VisibilityPolicy::OcclusionQueries,
        VisibilityPolicy::RayGuided,
        VisibilityPolicy::Both,
    ];

    /// True when the ray caster's usage counts feed visibility.
    pub fn ray_guided(self) -> bool {
        matches!(self, VisibilityPolicy::RayGuided | VisibilityPolicy::Both)
    }

    /// True when occlusion queries feed visibility.
    pub fn occlusion_queries(self) -> bool {
        matches!(
            self,
            VisibilityPolicy::OcclusionQueries | VisibilityPolicy::Both
        )
    }

    /// True when any feedback restricts refinement.
    pub fn culls(self) -> bool {
        self != VisibilityPolicy::None
    }

    /// A short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            VisibilityPolicy::None => "none",
            VisibilityPolicy::OcclusionQueries => "occlusion",
            VisibilityPolicy::RayGuided => "rayguided",
            VisibilityPolicy::Both => "both",
        }
    }
}
