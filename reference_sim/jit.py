"""How the simulator is compiled: five numba decorators, all with numpy's division semantics.

`compiled` functions may allocate arrays. `kernel` functions allocate nothing and are compiled
without numba's reference counting: in a counted function every call that passes arrays (the
`Model` alone holds 14) increments and decrements each array's count, an atomic operation that
in the step loops costs several times the arithmetic. Step loops and their helpers are kernels;
only the functions that allocate (contact lists, the sample table) are counted, and they are
called at most a few times a step. docs/contact-solver.md has the measurements.

Each sets `forceinline` explicitly: numba otherwise passes a caller's `forceinline` on to every
function first compiled while compiling it, so a helper's code would depend on which caller
compiled it first.
"""

from numba import njit

# error_model="numpy": a float division by zero gives inf or NaN, as in numpy, and the run ends
# as `diverged`; numba's default raises ZeroDivisionError from the compiled step, a traceback
# where the physics has merely blown up (found by tests/test_properties.py).
compiled = njit(cache=True, forceinline=False, error_model="numpy")
kernel = njit(cache=True, _nrt=False, forceinline=False, error_model="numpy")
# Kernels inlined by numba into each caller rather than called: a call passes every array of a
# `Model` (14) or `ContactBuffers` (40) argument by value, which in a step's dozen such calls
# costs more than the work; also for kernels of a single caller, as numba optimises each
# compiled function with all it calls again. numba inlines them in its own IR, before typing:
# each inlined copy is typed, lowered and optimised again (slow in numba's Python passes): the
# largest kernels of several callers are `shared_kernel`s instead.
inlined_kernel = njit(
    cache=True, _nrt=False, inline="always", forceinline=False, error_model="numpy"
)
# Large kernels of several callers (or called from a compile stage apart from their caller):
# compiled once per signature, cached, and inlined by LLVM into each caller (the `alwaysinline`
# attribute), which copies the optimised code in a fraction of the time numba's inlining takes;
# the step runs the same code without a call. A literal argument (a global constant) is typed
# as its value and makes a signature of its own: pass such arguments as `np.int64(...)`.
shared_kernel = njit(cache=True, _nrt=False, forceinline=True, error_model="numpy")
# Counted (allocating) functions inlined by numba into each caller: the seed's pair collision,
# run for every pair tested by several loops, where a call would count each array it is passed.
inlined = njit(cache=True, inline="always", forceinline=False, error_model="numpy")
