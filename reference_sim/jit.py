"""How the simulator is compiled: three numba decorators.

`compiled` functions may allocate arrays. `kernel` functions allocate nothing and are compiled
without numba's reference counting: in a counted function every call that passes arrays (the
`Model` alone holds 14) increments and decrements each array's count, an atomic operation,
which in the step loops cost several times the arithmetic (500 ns of a 600 ns free-flight
step, measured). Step loops and their helpers are kernels; only the functions that allocate
(contact lists, the sample table) are counted, and they are called at most a few times a step.
"""

from numba import njit

compiled = njit(cache=True)
kernel = njit(cache=True, _nrt=False)
# Kernels inlined by numba into each caller rather than called. A call passes every array of a
# `Model` (14) or `ContactBuffers` (35) argument by value, each as several words on the stack:
# in a step's dozen such calls the copying took about a fifth of a contact step and half of a
# free-flight one (`free_spin_cube` `euler` 196 -> 96 ns a step with the drift inlined;
# `incline` 2.93 -> 2.26 us with the solver's and assembly's calls inlined too). Each inlined
# copy is compiled again: the contact and rigid stages (`simulate.compile_stage`) now take 41
# and 61 s of CPU, about 30 and 22 before.
# Also for kernels with a single caller: numba optimises every compiled function together with
# all it calls, so each level of a deep call chain optimises the code below it again
# (measured: run_rigid, _steps and rigid_step each took 3-6 s of the ~47 s compile).
inlined_kernel = njit(cache=True, _nrt=False, inline="always")
