"""KITTI's download: the archive lists read (:mod:`.lists`), each archive fetched over HTTP
(:mod:`.transfer`), verified (:mod:`.verification`) and unpacked (:mod:`.extraction`), many at a time
(:mod:`.fetching`), and the archives the params need (:mod:`.kitti`)."""
