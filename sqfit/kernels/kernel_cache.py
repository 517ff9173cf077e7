"""Compiled kernels that call a kernel of another file: numba's on-disk cache does not see its changes.

numba invalidates a cached kernel when the file that defines it changes, not when a function it calls
from another file does (numba's documentation, "Notes on Caching": changes to symbols defined in
another file are not detected). The factor graph's silhouette kernel
(:mod:`sqfit.kernels.view_kernels`) calls the ray minimiser of :mod:`sqfit.kernels.ray_kernels`, 3H's
screen (:mod:`sqfit.kernels.screen_kernels`) its 3G rows, and the silhouette kernels its NaN-aware
minimum and maximum. So after a change of ``ray_kernels.py``
alone, a checkout kept loading the silhouette factors compiled against the old minimiser, while a fresh
clone compiled them against the new one: the same code gave other results (found in issue 23's
twenty-first pass: a checkout's cache from before the minimiser's slope fix of the nineteenth pass
was still used by the graph's silhouette factors a day later; docs/slam-history.md).

:func:`refresh` keeps a digest of every kernel module's source next to numba's cache files; where it
differs (or is missing), the cache files of all the kernel modules are removed, so each kernel is
compiled again against the sources it calls. :mod:`sqfit.kernels.ray_kernels` calls
:func:`refresh_for` when it is imported; the other kernel modules import it first, and no kernel runs
before. The cost: one digest of ~60 kB of source per process; a recompilation (about a minute on an
empty cache) only after a kernel source changed.
"""

from __future__ import annotations

import hashlib
import os

__all__ = ["KERNEL_MODULES", "STAMP", "source_digest", "refresh", "refresh_for"]

#: The modules of compiled kernels (in ``sqfit/kernels``), any of which may call another's kernels.
KERNEL_MODULES = ("ray_kernels", "screen_kernels", "silhouette_kernels", "view_kernels", "outline_kernels",
                  "hull_kernels", "union_kernels", "velocity_kernels")
#: File in numba's cache directory holding the digest of the sources its kernel files were compiled from.
STAMP = "sqfit-kernels.sha256"


def source_digest(sources):
    """SHA-256 (hex) of the kernel sources: ``sources`` maps a module name to its source file."""
    digest = hashlib.sha256()
    for name in sorted(sources):
        with open(sources[name], "rb") as f:
            digest.update(name.encode() + b"\0" + f.read() + b"\0")
    return digest.hexdigest()


def refresh(cache_dir, sources):
    """Remove the cache files of the modules in ``sources`` (module name -> source file) from
    ``cache_dir`` unless its stamp (:data:`STAMP`) holds their :func:`source_digest`, then write
    the stamp.

    numba's cache files of a module ``m`` are ``m.<function>-<line>.py<version>.nbi`` (index) and
    ``...nbc`` (code); nothing else there is touched. A directory that does not exist or cannot be
    written is left as it is (numba then cannot cache there either). Safe when processes race: a
    file another process removed first is skipped, and numba recompiles a kernel whose files are gone.

    Returns
    -------
    removed : int
        Cache files removed.
    """
    if not os.path.isdir(cache_dir):
        return 0
    digest = source_digest(sources)
    stamp = os.path.join(cache_dir, STAMP)
    try:
        with open(stamp, encoding="ascii") as f:
            if f.read().strip() == digest:
                return 0
    except (OSError, ValueError):
        pass
    prefixes = tuple(f"{name}." for name in sources)
    removed = 0
    try:
        for entry in os.listdir(cache_dir):
            if entry.startswith(prefixes) and entry.endswith((".nbi", ".nbc")):
                try:
                    os.remove(os.path.join(cache_dir, entry))
                    removed += 1
                except FileNotFoundError:
                    pass
        partial = f"{stamp}.{os.getpid()}"
        with open(partial, "w", encoding="ascii") as f:
            f.write(digest + "\n")
        os.replace(partial, stamp)
    except OSError:  # read-only: numba cannot write its cache here either
        pass
    return removed


def refresh_for(kernel):
    """:func:`refresh` of the kernel modules (:data:`KERNEL_MODULES`, beside ``kernel``'s source)
    in the cache directory numba uses for ``kernel`` (a ``cache=True`` dispatcher)."""
    from numba.core.caching import FunctionCache

    here = os.path.dirname(os.path.abspath(kernel.py_func.__code__.co_filename))
    sources = {name: os.path.join(here, f"{name}.py") for name in KERNEL_MODULES}
    sources = {name: path for name, path in sources.items() if os.path.isfile(path)}
    return refresh(FunctionCache(kernel.py_func).cache_path, sources)
