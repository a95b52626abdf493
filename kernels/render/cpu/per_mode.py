"""Kernels specialised per render mode, so a frame compiles its own mode's kernels and no other's.

A frame's mode reaches the kernels as a compile-time constant: each mode has its own entry
(launch.mode_entry) that passes its mode as a literal int, and numba hands literals on to the
kernels it calls. A call of a ``per_mode`` function then resolves, while numba types the caller,
to the implementation its ``choose`` returns for that mode; the other modes' code is never typed
or compiled (a reference frame used to compile every Gaussian kernel as well: 146 functions,
about a minute on a first run).
"""
from __future__ import annotations

import inspect

from numba.core import types
from numba.core.errors import TypingError
from numba.extending import overload

from ...mode_names import Mode

# A band kernel's constant is its mode, plus this bit for a reference frame of one fog volume in
# Emission with a linear transfer function (launch.kernel_code): such a frame compiles only the
# one-fog sampler (cpu.fog), any other reference frame only the general one (cpu.pieces).
ONE_FOG = 1 << 8
MODE_BITS = ONE_FOG - 1


def _literal(mode_type, where: str) -> int:
    if not isinstance(mode_type, types.IntegerLiteral):
        raise TypingError(f"{where}: the render mode must be a compile-time constant "
                          "(draw through cpu.launch.mode_entry)")
    return mode_type.literal_value


def literal_mode(mode_type, where: str) -> Mode:
    """The Mode a numba literal int type names; a TypingError when the mode is not a constant."""
    return Mode(_literal(mode_type, where) & MODE_BITS)


def _register(stub, pick):
    def typer(*args):
        return pick(args[0])

    typer.__signature__ = inspect.signature(stub)  # numba checks implementations against it
    overload(stub, inline="always", prefer_literal=True)(typer)


def per_mode(stub):
    """Decorator of ``choose(mode: Mode) -> implementation``: calls of ``stub`` (a plain function
    whose first argument is the mode) from jitted code run that implementation, inlined. The
    implementation takes the stub's arguments."""
    def register(choose):
        _register(stub, lambda t: choose(literal_mode(t, stub.__name__)))
        return choose
    return register


def per_kernel(stub):
    """per_mode whose ``choose(mode, one_fog: bool)`` also sees the ONE_FOG bit."""
    def register(choose):
        _register(stub, lambda t: choose(literal_mode(t, stub.__name__),
                                         bool(_literal(t, stub.__name__) & ONE_FOG)))
        return choose
    return register
