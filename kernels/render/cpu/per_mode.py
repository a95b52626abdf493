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
from dataclasses import dataclass

from numba.core import types
from numba.core.errors import TypingError
from numba.extending import overload

from ...mode_names import Mode

# A band kernel's constant is its mode plus bits for what its scenes leave out
# (launch.kernel_code), so such a frame compiles none of that code:
ONE_FOG = 1 << 8  # reference: one fog volume in Emission, a linear transfer function: only the
                  # one-fog sampler (cpu.fog); any other reference frame only cpu.pieces'
PLAIN = 1 << 9    # particles: no lit volume and no surface (no shading code)
MODE_BITS = ONE_FOG - 1


@dataclass(frozen=True)
class Variant:
    """The bits of a band kernel's constant besides its mode."""
    one_fog: bool
    plain: bool  # no lit volume, no surface (ONE_FOG frames are plain too)


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


def literal_variant(mode_type, where: str) -> Variant:
    code = _literal(mode_type, where)
    return Variant(one_fog=bool(code & ONE_FOG), plain=bool(code & (ONE_FOG | PLAIN)))


def per_kernel(stub):
    """per_mode whose ``choose(mode, variant: Variant)`` also sees the constant's other bits."""
    def register(choose):
        _register(stub, lambda t: choose(literal_mode(t, stub.__name__),
                                         literal_variant(t, stub.__name__)))
        return choose
    return register
