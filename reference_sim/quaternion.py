"""The quaternion formulas of `rigidmath.quaternion`, compiled as allocation-free kernels for
the step loops (4-tuples in and out, scalar first)."""

from reference_sim.jit import kernel
from rigidmath import quaternion as formulas

qmul = kernel(formulas.qmul)
qnormalize = kernel(formulas.qnormalize)
qexp = kernel(formulas.qexp)
qmatrix = kernel(formulas.qmatrix)
qfrom_matrix = kernel(formulas.qfrom_matrix)
