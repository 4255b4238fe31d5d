"""How the simulator is compiled: two numba decorators.

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
# Kernels with a single caller in the step loop, inlined into it by numba rather than compiled on
# their own: numba optimises every compiled function together with all it calls, so each level
# of a deep call chain optimises the code below it again (measured: run_rigid, _steps and
# rigid_step each took 3-6 s of the ~47 s compile, mostly optimising the contact code again).
inlined_kernel = njit(cache=True, _nrt=False, inline="always")
