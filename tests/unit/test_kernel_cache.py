"""numba's on-disk cache stays true to the source (swarm.kernel_cache): a real package of
two files, a cached kernel calling a kernel of the other file, compiled by real numba in
child processes."""

import subprocess
import sys
from pathlib import Path

from swarm.kernel_cache import STAMP, clear_stale

CALLEE = "from numba import njit\n\n@njit(cache=True)\ndef f(x):\n    return x + {n}\n"
CALLER = "from numba import njit\nfrom pkg.a import f\n\n@njit(cache=True)\ndef g(x):\n    return f(x) * 10\n"
RUN = "import sys; sys.path.insert(0, {root!r}); {clear}from pkg.b import g; print(g(1))"
CLEAR = "from pathlib import Path; from swarm.kernel_cache import clear_stale; clear_stale([Path({root!r}) / 'pkg']); "


def make_package(root: Path, n: int) -> None:
    pkg = root / "pkg"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text(CALLEE.format(n=n))
    (pkg / "b.py").write_text(CALLER)


def g_of_1(root: Path, clear: bool) -> int:
    code = RUN.format(root=str(root), clear=CLEAR.format(root=str(root)) if clear else "")
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120, check=True)
    return int(out.stdout.strip())


def test_a_changed_callee_in_another_file_is_recompiled(tmp_path):
    make_package(tmp_path, 1)
    assert g_of_1(tmp_path, clear=True) == 20  # compiled and cached
    # the callee changes (its size too: Python's own bytecode cache goes by size and whole
    # seconds of mtime), the caller's file does not
    make_package(tmp_path, 12)
    assert g_of_1(tmp_path, clear=False) == 20  # numba alone: the caller's cache, stale
    assert g_of_1(tmp_path, clear=True) == 130  # cleared: compiled anew from the source


def test_the_cache_is_kept_while_no_source_changes(tmp_path):
    make_package(tmp_path, 1)
    pkg = tmp_path / "pkg"
    cache = pkg / "__pycache__"
    cache.mkdir()
    (cache / "b.g-4.py311.nbi").write_bytes(b"index")
    assert clear_stale([pkg])  # no stamp yet: cleared, stamped
    assert (cache / STAMP).is_file() and not (cache / "b.g-4.py311.nbi").exists()
    (cache / "b.g-4.py311.nbi").write_bytes(b"index")
    assert not clear_stale([pkg])  # the same sources: kept
    assert (cache / "b.g-4.py311.nbi").exists()
    (pkg / "a.py").write_text(CALLEE.format(n=3))
    assert clear_stale([pkg])  # a source changed: cleared
    assert not (cache / "b.g-4.py311.nbi").exists()
