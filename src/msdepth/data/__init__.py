"""Data: KITTI's on-disk formats, stereo folders, each source's layout, and the indexes and ROIs
the stages read."""
