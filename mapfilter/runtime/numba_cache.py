"""Kernels loaded from numba's cache without numba's whole compiler being set up.

Before it loads a cached kernel, numba refreshes its target context: it imports its whole
library of implementations (numpy's linear algebra, which imports scipy.linalg, typed
containers, random generators, ...) and registers each, about a third of a command's start-up on
a walk of a minute, though a cached kernel is machine code that links against numba's runtime
(NRT) alone. :func:`install` makes a cache load initialise that runtime and nothing else. What
compiles (a kernel not in the cache, a new model's) still gets the whole context: numba's compiler
refreshes it itself before it compiles, and the context is refreshed the first time code is
lowered.

This reaches into numba's private loader (``numba.core.caching.Cache.load_overload``), so it
replaces it only when it is the loader this was written against (numba 0.60 to 0.68: it calls
``target_context.refresh()`` then ``self._load_overload(sig, target_context)``); on any other numba
it leaves numba alone and start-up is as numba makes it (``tests/runtime/test_numba_cache.py``
fails loudly when that happens on the numba a checkout is tested with).
"""

from __future__ import annotations

import sys

__all__ = ["install", "installed"]

_MODULE = "numba.core.caching"
# what numba's own loader refers to: refresh the context, then load under its I/O guard
_EXPECTED_NAMES = {"refresh", "_guard_against_spurious_io_errors", "_load_overload"}


def installed() -> bool:
    """True when cache loads skip numba's context refresh (the loader was replaced)."""
    caching = sys.modules.get(_MODULE)
    return caching is not None and getattr(caching.Cache.load_overload, "_mapfilter", False)


def install() -> None:
    """Replace numba's cache loader now if numba's caching module is imported, else as soon as it
    is (an import hook that removes itself): every kernel load, from the first, skips the refresh.
    Does nothing when the loader is not the one this module knows."""
    caching = sys.modules.get(_MODULE)
    if caching is not None:
        _replace(caching)
    elif not any(isinstance(finder, _WhenImported) for finder in sys.meta_path):
        sys.meta_path.insert(0, _WhenImported())


def _replace(caching) -> None:
    original = caching.Cache.load_overload
    if getattr(original, "_mapfilter", False) or not _EXPECTED_NAMES <= set(original.__code__.co_names):
        return
    from numba.core.runtime import rtsys

    def load_overload(self, sig, target_context):
        # the runtime a cached kernel links against; the rest of the context waits for a compile
        rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    load_overload._mapfilter = True
    load_overload.__doc__ = original.__doc__
    caching.Cache.load_overload = load_overload


class _WhenImported:
    """A meta path finder that finds nothing itself; when numba's caching module is imported, lets
    the normal finders load it and then replaces its loader."""

    def find_spec(self, name, path=None, target=None):
        if name != _MODULE:
            return None
        import importlib.util

        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        spec.loader = _ThenReplace(spec.loader)
        return spec


class _ThenReplace:
    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        self._loader.exec_module(module)
        _replace(module)

    def __getattr__(self, name):  # get_source, get_filename, ...: the real loader's
        return getattr(self._loader, name)
