"""How the simulator is compiled: three numba decorators.

`compiled` functions may allocate arrays. `kernel` functions allocate nothing and are compiled
without numba's reference counting: in a counted function every call that passes arrays (the
`Model` alone holds 14) increments and decrements each array's count, an atomic operation that
in the step loops costs several times the arithmetic. Step loops and their helpers are kernels;
only the functions that allocate (contact lists, the sample table) are counted, and they are
called at most a few times a step. docs/contact-solver.md has the measurements.
"""

from numba import njit

compiled = njit(cache=True)
kernel = njit(cache=True, _nrt=False)
# Kernels inlined by numba into each caller rather than called: a call passes every array of a
# `Model` (14) or `ContactBuffers` (40) argument by value, which in a step's dozen such calls
# costs more than the work; also for kernels of a single caller, as numba optimises each
# compiled function with all it calls again. Each inlined copy is compiled again.
inlined_kernel = njit(cache=True, _nrt=False, inline="always")
