"""Keeps numba's on-disk cache of the compiled kernels true to the source.

numba re-compiles a cached kernel when the file that defines it changes, but not when a
kernel it calls from another file does: after an edit of ``swarm/safety/constraints.py`` the cached
``swarm.safety.filter._prepare`` still runs the old ``rows_kernel``, silently (found while
changing the rows). :func:`clear_stale` drops every cached kernel of the package once any
of its source files has changed, by a hash of all of them kept beside the cache.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

STAMP = "kernels.sha1"
"""The file, in the package's ``__pycache__``, that holds the hash of the sources the cache was made from."""


def clear_stale(dirs: list[Path]) -> bool:
    """Delete numba's cache files (``__pycache__/*.nbi``, ``*.nbc``) under ``dirs`` if the
    hash of their ``*.py`` files differs from the stamp in ``dirs[0]/__pycache__``, then
    write the stamp. Returns whether anything was cleared. A folder that cannot be written
    (a read-only install) is left as it is; a cache elsewhere (``NUMBA_CACHE_DIR``) is not
    touched."""
    sources = sorted(p for d in dirs for p in d.rglob("*.py"))
    digest = hashlib.sha1()
    for p in sources:
        digest.update(p.as_posix().encode())
        digest.update(p.read_bytes())
    stamp = dirs[0] / "__pycache__" / STAMP
    try:
        if stamp.read_text() == digest.hexdigest():
            return False
    except OSError:
        pass  # no stamp yet
    try:
        for d in dirs:
            for f in [*d.rglob("__pycache__/*.nbi"), *d.rglob("__pycache__/*.nbc")]:
                f.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        tmp = stamp.with_name(f"{STAMP}.{os.getpid()}")
        tmp.write_text(digest.hexdigest())
        tmp.replace(stamp)  # atomic: processes starting together read a whole stamp or none
    except OSError:
        return False
    return True
