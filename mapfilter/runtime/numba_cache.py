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

A cached kernel also carries the environment of every function compiled into it, numba's own
too (the array allocation of ``numba.np.arrayobj``), and numba rebuilds each with its module's
globals, importing the module (``numba.core.environment._rebuild_env``): 0.05 s of a one-walk
track for ``numba.np.arrayobj`` alone. Those globals are read by object-mode code only, which no
kernel here has (``nopython``: its constants are in the environment's ``consts``, which are
restored), so an environment of a module not imported yet gets a dictionary with the module's
name instead. Replaced only when numba's function is the one this knows (it imports the module,
makes an ``Environment`` of its dictionary and keeps it by name).

And a cached kernel comes with its LLVM bitcode, which numba parses at once (0.055 s of the 0.9 MB
of the 23 kernels a one-walk track loads) for two things: the names the kernel defines, which its
machine code's own ELF symbol table gives as well (the same names, ``tests/runtime/test_numba_cache.py``),
and linking a later compile against the kernel, which is rare in a run. So the bitcode is parsed
when a compile first links against the kernel (``_get_module_for_linking``). Replaced only when
numba's library loader is the one this knows and the machine code is a 64-bit little-endian ELF
object (else as numba loads it).
"""

from __future__ import annotations

import sys

__all__ = ["install", "installed"]

_MODULE = "numba.core.caching"
# what numba's own loader refers to: refresh the context, then load under its I/O guard
_EXPECTED_NAMES = {"refresh", "_guard_against_spurious_io_errors", "_load_overload"}
# what numba's own environment rebuild refers to: the memo, the module's import, a new Environment
_EXPECTED_ENV_NAMES = {"lookup_environment", "importlib", "import_module", "Environment", "_memo"}
# what numba's own library loader refers to (for machine code: the object, the bitcode's parse,
# the module made ready, the names it defines) and what its linking module is made of
_EXPECTED_LIBRARY_NAMES = {"create_library", "enable_object_caching", "_set_compiled_object", "parse_bitcode",
                           "_shared_module", "_finalize_final_module", "_load_defined_symbols"}
_EXPECTED_LINKING_NAMES = {"_ensure_finalized", "_shared_module", "_final_module"}


def installed() -> bool:
    """True when cache loads skip numba's context refresh (the loader was replaced) and the
    import of modules whose environments a kernel carries (the environment rebuild was replaced)."""
    caching = sys.modules.get(_MODULE)
    environment = sys.modules.get("numba.core.environment")
    codegen = sys.modules.get("numba.core.codegen")
    return (caching is not None and getattr(caching.Cache.load_overload, "_mapfilter", False)
            and environment is not None and getattr(environment._rebuild_env, "_mapfilter", False)
            and codegen is not None and getattr(codegen.CPUCodeLibrary._unserialize, "_mapfilter", False))


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
    _replace_environment_rebuild()
    _replace_library_load()


def _replace_environment_rebuild() -> None:
    from numba.core import environment

    original = environment._rebuild_env
    if getattr(original, "_mapfilter", False) or not _EXPECTED_ENV_NAMES <= set(original.__code__.co_names):
        return

    def _rebuild_env(modname, consts, env_name):
        env = environment.lookup_environment(env_name)
        if env is not None:
            return env
        module = sys.modules.get(modname)
        # a module not imported: its globals are for object-mode code, which no cached kernel has
        env = environment.Environment(module.__dict__ if module is not None else {"__name__": modname})
        env.consts[:] = consts
        env.env_name = env_name
        environment.Environment._memo[env_name] = env
        return env

    _rebuild_env._mapfilter = True
    _rebuild_env.__doc__ = original.__doc__
    # an environment pickled by this process names numba's function, as it would without this one
    _rebuild_env.__module__, _rebuild_env.__qualname__ = original.__module__, original.__qualname__
    environment._rebuild_env = _rebuild_env


def _replace_library_load() -> None:
    from numba.core import codegen

    library = codegen.CPUCodeLibrary
    original = library._unserialize.__func__
    linking = library._get_module_for_linking
    if (getattr(original, "_mapfilter", False) or not _EXPECTED_LIBRARY_NAMES <= set(original.__code__.co_names)
            or not _EXPECTED_LINKING_NAMES <= set(linking.__code__.co_names)):
        return
    from llvmlite import binding as ll

    def _unserialize(cls, codegen_, state):
        name, kind, data = state
        symbols = elf_defined_symbols(data[0]) if kind == "object" else None
        if symbols is None:
            return original(cls, codegen_, state)
        object_code, shared_bitcode = data
        self = codegen_.create_library(name)
        self.enable_object_caching()
        self._set_compiled_object(object_code)
        self._mapfilter_bitcode = shared_bitcode  # parsed when a compile links against this library
        self._finalize_final_module()
        codegen_._engine._defined_symbols |= symbols
        return self

    def _get_module_for_linking(self):
        bitcode = getattr(self, "_mapfilter_bitcode", None)
        if bitcode is not None and self._shared_module is None:
            self._shared_module = ll.parse_bitcode(bitcode)
            self._mapfilter_bitcode = None
        return linking(self)

    _unserialize._mapfilter = True
    _get_module_for_linking.__doc__ = linking.__doc__
    library._unserialize = classmethod(_unserialize)
    library._get_module_for_linking = _get_module_for_linking


def elf_defined_symbols(object_code: bytes) -> set[str] | None:
    """The names a 64-bit little-endian ELF object defines (its symbol table's entries that are in
    a section, neither a section's nor a file's own name); None for anything else."""
    import struct

    if len(object_code) < 64 or object_code[:6] != b"\x7fELF\x02\x01":
        return None
    try:
        section_offset, = struct.unpack_from("<Q", object_code, 0x28)
        entry_size, count = struct.unpack_from("<HH", object_code, 0x3A)
        sections = [struct.unpack_from("<IIQQQQIIQQ", object_code, section_offset + i * entry_size)
                    for i in range(count)]
        names: set[str] = set()
        for _, kind, _, _, offset, size, link, _, _, _ in sections:
            if kind != 2:  # SHT_SYMTAB
                continue
            strings = sections[link][4]
            for k in range(size // 24):
                name, info, _, section, _, _ = struct.unpack_from("<IBBHQQ", object_code, offset + 24 * k)
                if section == 0 or (info & 0xF) in (3, 4) or name == 0:  # undefined, STT_SECTION, STT_FILE
                    continue
                start = strings + name
                names.add(object_code[start:object_code.index(b"\0", start)].decode())
        return names
    except (struct.error, ValueError, IndexError, UnicodeDecodeError):
        return None


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
