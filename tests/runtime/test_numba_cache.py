"""Kernels loaded from numba's cache without numba's whole context (runtime/numba_cache.py)."""

import subprocess
import sys
import textwrap

_CHILD = textwrap.dedent("""
    import sys

    import numpy as np

    import mapfilter
    from mapfilter.runtime.numba_cache import installed
    from mapfilter.filter.models.motion import RandomWalkMotion
    from mapfilter.filter.particle_filter import FilterConfig, ParticleFilter
    from mapfilter.maps.floorplan import FloorPlan

    # a wall in a corner: the kill path runs, and the cloud stays whole (a cloud split by a wall
    # has its track walk round it, which loads scipy's graph search, and scipy.linalg with it)
    wall = np.zeros((40, 40), dtype=bool)
    wall[:8, :8] = True
    pf = ParticleFilter(FloorPlan(wall, 0.1), RandomWalkMotion(), FilterConfig(n_particles=500),
                        np.random.default_rng(0))
    pf.initialise_uniform()
    for _ in range(3):
        pf.step(0.0, 1.0, None, None, None)
    loaded_only = "numba.np.arraymath" not in sys.modules and "scipy.linalg" not in sys.modules
    # the kernels carry numba.np.arrayobj's environments (their arrays' allocation): not imported for them
    no_arrayobj = "numba.np.arrayobj" not in sys.modules

    # a kernel that is in no cache still compiles (numba's compiler sets its context up itself)
    from numba import njit

    @njit
    def norm_and_dot(x):
        return np.linalg.norm(x) + np.dot(x, x)

    print(installed(), loaded_only and no_arrayobj, norm_and_dot(np.ones(3)))
""")


def test_cached_kernels_load_without_numbas_whole_context_and_new_ones_still_compile():
    runs = [subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, timeout=600)
            for _ in range(2)]  # the first fills numba's cache if a kernel changed
    assert runs[1].returncode == 0, runs[1].stderr[-2000:]
    replaced, loaded_only, value = runs[1].stdout.split()
    assert replaced == "True", ("numba's cache loader is not the one mapfilter/runtime/numba_cache.py replaces "
                                "(another numba?): every command pays numba's whole context at start-up")
    assert loaded_only == "True"  # no numba.np.arraymath, no scipy.linalg, no numba.np.arrayobj
    assert float(value) == 3.0 + 3.0 ** 0.5


def test_the_warm_up_removes_numbas_cache_files_of_the_package_and_nothing_else(tmp_path):
    """A reinstall compiles every kernel afresh: numba checks a cached kernel against its own file
    only, so one that calls a changed kernel of another module would load stale. Only numba's
    index and data files in the ``__pycache__`` folders go; the sources, the bytecode and any other
    file stay."""
    from mapfilter.runtime.warmup import clear_kernel_cache

    stale = [tmp_path / "filter" / "__pycache__" / "kernels.step-12.py311.nbi",
             tmp_path / "filter" / "__pycache__" / "kernels.step-12.py311.1.nbc",
             tmp_path / "__pycache__" / "estimate._mode-40.py311.nbi"]
    kept = [tmp_path / "filter" / "kernels.py", tmp_path / "filter" / "__pycache__" / "kernels.cpython-311.pyc",
            tmp_path / "notes" / "run.nbi"]  # not in a __pycache__ folder: not numba's
    for path in stale + kept:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"x")
    assert clear_kernel_cache(tmp_path) == len(stale)
    assert not any(p.exists() for p in stale) and all(p.exists() for p in kept)


_LINK_CHILD = textwrap.dedent("""
    import numpy as np
    from llvmlite import binding as ll
    from numba import njit
    from numba.core import codegen

    from mapfilter.runtime.numba_cache import elf_defined_symbols, installed

    replaced = installed()
    # every kernel loaded from the cache: the names its machine code defines are those of its bitcode
    loaded = codegen.CPUCodeLibrary._unserialize.__func__
    checked = []

    def checking(cls, codegen_, state):
        name, kind, data = state
        if kind == "object":
            module = ll.parse_bitcode(data[1])
            ir_names = {g.name for group in (module.functions, module.global_variables) for g in group
                        if not g.is_declaration}
            checked.append(elf_defined_symbols(data[0]) == ir_names and len(ir_names) > 0)
        return loaded(cls, codegen_, state)

    codegen.CPUCodeLibrary._unserialize = classmethod(checking)
    from mapfilter.filter.models.radio_map import _offset

    log_p, log_var, log_not_p = np.log([0.5, 0.2]), np.log([30.0, 60.0]), np.log1p(-np.array([0.5, 0.2]))
    direct = _offset(log_p, log_var, log_not_p)
    library = _offset.overloads[_offset.signatures[0]].library
    lazy = library._shared_module is None  # loaded without its bitcode parsed

    # a new kernel that calls the cached one links against it: the bitcode is parsed then
    @njit
    def twice(a, b, c):
        return 2.0 * _offset(a, b, c)

    linked = twice(log_p, log_var, log_not_p)
    print(replaced, len(checked) > 0 and all(checked), lazy, library._shared_module is not None,
          bool(np.array_equal(linked, 2.0 * direct)))
""")


def test_kernels_load_without_their_bitcode_and_a_new_kernel_still_links_against_them():
    runs = [subprocess.run([sys.executable, "-c", _LINK_CHILD], capture_output=True, text=True, timeout=600)
            for _ in range(2)]  # the first fills numba's cache if a kernel changed
    assert runs[1].returncode == 0, runs[1].stderr[-2000:]
    replaced, same_names, lazy, parsed_when_linked, same_numbers = runs[1].stdout.split()
    assert replaced == "True"
    assert same_names == "True"  # the ELF object's names are the bitcode's, for every kernel loaded
    assert lazy == "True" and parsed_when_linked == "True"
    assert same_numbers == "True"
