"""KITTI's download: archives fetched, verified and unpacked (:mod:`.archives`), and the archives the
params need (:mod:`.kitti`)."""
