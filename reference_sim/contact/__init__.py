"""Contact for the rigid integrators: impulses, not penalties, and nothing but impulses.

Impulses have no stiffness, so contact costs no step-size limit and a resting body sits exactly
on the surface; every contact effect is an equal and opposite impulse at one contact point (no
position correction), so a collision conserves linear and angular momentum exactly. Each step is
split around the drift: speculative contacts before it, bounce and rest after it, solved by
projected Gauss-Seidel with Coulomb friction. docs/contact-solver.md explains the solver, each
mechanism and the measurements behind it.

Modules, in the order a step uses them:

- `settings`: the tuned constants and `describe`, the solver's description for a run manifest.
- `buffers`: `ContactBuffers`, the work space of a run, and the names of its counters.
- `frames`: body frames, particle positions, how far a body can move in a step.
- `candidates`, `grid`, `pair_list`: the broad phase, pair by pair, on a uniform grid, or from
  the grid's pairs kept between steps (a pile's).
- `rows`: assembly of gaps, Jacobian rows and inverse masses; standby and waking.
- `impulses`: a contact's speed along a row, applying and projecting impulses.
- `warm_start`: starting from last step's impulses and their trend.
- `gauss_seidel`: the sweeps, their stopping rules, idle contacts and extrapolation.
- `subspace`: the subspace steps for a stack's slow modes.
- `step`: `before_drift` and `after_drift`, what `reference_sim.rigid` calls.
"""
