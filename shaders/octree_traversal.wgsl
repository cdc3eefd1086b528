// Octree traversal library (work in progress).
