"""c3swarm: the pure core (model, barriers, safety filter, reference control).

Importing it first drops numba's cached kernels if any source file changed since they were
compiled (:mod:`swarm.kernel_cache`): numba alone would keep a kernel whose callee in
another file changed."""

import os as _os
from pathlib import Path as _Path

if not _os.environ.get("NUMBA_CACHE_DIR"):  # (a cache elsewhere is the caller's to manage)
    from swarm.kernel_cache import clear_stale as _clear_stale
    from swarm.kernel_cache import source_dirs as _source_dirs

    _clear_stale(_source_dirs(_Path(__file__).resolve().parent))
