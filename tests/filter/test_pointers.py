"""numba's private function-pointer API, as ``filter.kernels.pointers`` uses it: each test fails with
a message that names that module when a numba release changes what it relies on."""

from __future__ import annotations

import re
from pathlib import Path

import numba
import numpy as np
import pytest
from numba import njit, types

from mapfilter.filter.kernels import pointers
from mapfilter.filter.kernels.passes import LIKELIHOOD_SIGNATURE, MOVE_SIGNATURE, X, Y

CHANGED = (f"numba {numba.__version__} changed what mapfilter/filter/kernels/pointers.py relies on (checked on "
           f"numba {pointers.TESTED_NUMBA[0]} to {pointers.TESTED_NUMBA[1]})")


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(part) for part in re.findall(r"\d+", text)[:2])


def test_the_installed_numba_is_one_the_module_was_checked_on_and_pyproject_admits_only_those():
    first, last = (_version(v) for v in pointers.TESTED_NUMBA)
    assert first <= _version(numba.__version__) <= last, (
        f"numba {numba.__version__} is outside {pointers.TESTED_NUMBA}: run this file on it, then widen "
        "TESTED_NUMBA and pyproject.toml's numba pin together")
    root = Path(__file__).resolve().parents[2]
    # the project's dependency, and the build environment's that compiles the kernels at install
    for path in (root / "pyproject.toml", root / "build_backend" / "mapfilter_build.py"):
        pin = re.search(r'"numba>=([0-9.]+),<([0-9.]+)"', path.read_text())
        assert pin, f"{path.name} pins numba to a range: numba>=FIRST,<NEXT"
        assert _version(pin.group(1)) == first and _version(pin.group(2)) == (last[0], last[1] + 1), path.name


def test_numba_still_has_the_private_address_functions():
    from numba.experimental import function_type

    for name in ("_get_wrapper_address", "_get_jit_address"):
        assert callable(getattr(function_type, name, None)), f"{CHANGED}: function_type.{name} is gone"


def test_a_first_class_function_is_still_the_struct_of_three_addresses():
    from numba.core.registry import cpu_target

    model = cpu_target.target_context.data_model_manager.lookup(types.FunctionType(LIKELIHOOD_SIGNATURE))
    members = list(zip(model._fields, model._members))
    assert members == [("c_addr", types.voidptr), ("py_addr", types.voidptr), ("jit_addr", types.voidptr)], (
        f"{CHANGED}: types.FunctionType's data model is now {members}")


@njit(LIKELIHOOD_SIGNATURE, cache=True, nogil=True)
def _distance_to_point(params, state, lo, m, out):
    for j in range(m):
        out[j] = -((state[X, lo + j] - params[0]) ** 2 + (state[Y, lo + j] - params[1]) ** 2)


@njit(MOVE_SIGNATURE, cache=True, nogil=True)
def _shift_by_normals(params, src, dst, normals, lo, m):
    for row in range(src.shape[0]):
        for j in range(m):
            dst[row, lo + j] = src[row, lo + j]
    for j in range(m):
        dst[X, lo + j] += params[0] * normals[0, j]
        dst[Y, lo + j] += params[0] * normals[1, j]


_likelihood_at = pointers.function_at(LIKELIHOOD_SIGNATURE)
_move_at = pointers.function_at(MOVE_SIGNATURE)


@njit(cache=True)
def _call_likelihood(c_address, jit_address, params, state, out):
    function = _likelihood_at(c_address, jit_address)
    function(params, state, 1, state.shape[1] - 1, out)


@njit(cache=True)
def _call_move(c_address, jit_address, params, src, dst, normals):
    function = _move_at(c_address, jit_address)
    function(params, src, dst, normals, 0, src.shape[1])


def test_a_kernel_called_through_its_addresses_computes_what_it_computes_when_called_itself():
    rng = np.random.default_rng(0)
    state = np.ascontiguousarray(rng.normal(0.0, 5.0, (6, 40)))
    params = np.array([1.5, -2.0])
    address = pointers.pointer(_distance_to_point, LIKELIHOOD_SIGNATURE)
    assert isinstance(address, pointers.FunctionPointer) and address.c_address > 0 and address.jit_address > 0
    through = np.full(40, np.nan)
    _call_likelihood(address.c_address, address.jit_address, params, state, through)
    direct = np.full(40, np.nan)
    _distance_to_point(params, state, 1, 39, direct)
    assert np.array_equal(through[:39], direct[:39]), f"{CHANGED}: a call through the addresses gave other values"
    assert np.isnan(through[39])  # it wrote the 39 values asked for, no more

    normals = np.ascontiguousarray(rng.normal(size=(6, 40)))
    move = pointers.pointer(_shift_by_normals, MOVE_SIGNATURE)
    moved = np.zeros_like(state)
    _call_move(move.c_address, move.jit_address, np.array([0.5]), state, moved, normals)
    expected = state.copy()
    expected[X] += 0.5 * normals[0]
    expected[Y] += 0.5 * normals[1]
    assert np.array_equal(moved, expected), f"{CHANGED}: a move through the addresses gave other values"


def test_what_is_no_kernel_for_the_signature_is_refused():
    def plain(params, state, lo, m, out):
        pass

    @njit
    def wrong(params, state, lo, m, out):
        out[j] = params.no_such_attribute  # noqa: F821

    for function in (plain, wrong):
        with pytest.raises(TypeError, match="no numba kernel"):
            pointers.pointer(function, LIKELIHOOD_SIGNATURE)
