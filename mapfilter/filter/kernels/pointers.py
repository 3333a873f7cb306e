"""Models' compiled kernels as function pointers: the one module that reaches into numba's private API.

The passes take a model's kernel as the two addresses of its compiled code
(:class:`FunctionPointer`) and rebuild a first-class numba function from them inside the pass
(:func:`function_at`): numba's own unboxing of a function argument costs tens of microseconds per
call. Three things used here are numba's internals, not its public API; they hold on the numba
versions that ``pyproject.toml`` admits (``TESTED_NUMBA``), and ``tests/filter/test_pointers.py``
fails with a message naming this module when a numba release changes one of them:

- ``numba.experimental.function_type._get_wrapper_address`` and ``_get_jit_address``: the
  addresses of a dispatcher's C wrapper and of its compiled function for one signature;
- the data model of ``types.FunctionType``: a struct of the addresses ``c_addr``, ``py_addr``
  and ``jit_addr``;
- a call of such a struct goes to ``jit_addr`` with numba's own calling convention (what
  numba emits for a first-class function whose compiled function it knows).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["FUNCTION_POINTER", "TESTED_NUMBA", "FunctionPointer", "function_at", "pointer"]

# the numba releases this module was checked on, [first, last] (pyproject.toml admits these)
TESTED_NUMBA = ("0.61", "0.68")


class FunctionPointer(NamedTuple):
    """The compiled code of one kernel for one signature: its C wrapper's address and its own."""

    c_address: np.uint64
    jit_address: np.uint64


FUNCTION_POINTER = types.NamedTuple((types.uint64, types.uint64), FunctionPointer)


def _private(name: str):
    from numba.experimental import function_type

    found = getattr(function_type, name, None)
    if found is None:
        raise ImportError(f"numba {numba.__version__} has no numba.experimental.function_type.{name}, which "
                          f"mapfilter.filter.kernels.pointers needs (checked on numba {TESTED_NUMBA[0]} to "
                          f"{TESTED_NUMBA[1]}): install a numba in that range")
    return found


_POINTERS: dict = {}


def pointer(function, signature) -> FunctionPointer:
    """The addresses of ``function`` (a numba dispatcher) compiled with ``signature``."""
    found = _POINTERS.get(function)  # a kernel has one signature (hashing numba's types is slow)
    if found is None:
        get_wrapper_address, get_jit_address = _private("_get_wrapper_address"), _private("_get_jit_address")
        try:
            c_address = get_wrapper_address(function, signature)
            jit_address = get_jit_address(function, signature)
        except (NotImplementedError, numba.core.errors.NumbaError) as error:
            raise TypeError(f"{function!r} is no numba kernel that compiles for {signature}: {error}") from error
        if not (c_address > 0 and jit_address > 0):
            raise TypeError(f"{function!r} is no numba kernel that compiles for {signature}")
        found = _POINTERS[function] = FunctionPointer(np.uint64(c_address), np.uint64(jit_address))
    return found


def function_at(signature):
    """An intrinsic ``make(c_address, jit_address)`` that gives the first-class function of
    ``signature`` at those addresses, to call inside a kernel."""
    function_type = types.FunctionType(signature)

    @intrinsic
    def make(typingctx, c_address, jit_address):
        def codegen(context, builder, sig, args):
            value = cgutils.create_struct_proxy(function_type)(context, builder)
            void_pointer = context.get_value_type(types.voidptr)
            value.c_addr = builder.inttoptr(args[0], void_pointer)
            value.py_addr = ir.Constant(void_pointer, None)
            value.jit_addr = builder.inttoptr(args[1], void_pointer)  # called directly (numba's convention)
            return value._getvalue()
        return function_type(types.uint64, types.uint64), codegen

    return make
