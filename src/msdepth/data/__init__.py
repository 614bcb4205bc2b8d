"""Data: readers and writers for KITTI's on-disk formats, and the procedural stereo set."""
