//! The octree-with-ropes spatial index (work in progress; see issue 4).
