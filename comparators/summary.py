"""One run's headline numbers, the row a sweep or `rigidbench run` shows: its timing and
solver report, the metrics (`comparators.metrics`) and the verdict (`comparators.verdict`).
"""

from __future__ import annotations

import numpy as np

from cases.exact import exact_states, exact_trajectory_available
from cases.scene import Scene
from comparators.engine_output import first_message, message_count
from comparators.metrics import body_arrays, drifts, pose_errors, rest
from comparators.run_data import RunData
from comparators.trajectory import Trajectory
from comparators.verdict import energy_growth, verdict


def summarize(traj: Trajectory, scene: Scene) -> dict[str, float | str | bool]:
    """One run's headline numbers: speed, drifts, the energy gain (the largest rise of total
    energy above its start, relative to the energy the scene can put into motion: a contact may
    only take energy away; `comparators.verdict.energy_growth`), pose error against the exact
    solution where the scene has one (largest over the run, and the orientation error at the
    end), largest shape error (deforming engines), rest (where the scene predicts a rest
    height), what the engine said while it ran (`engine_messages`: lines, and the first one
    where there is one) and the verdict (`comparators.verdict.verdict`: ok, diverged,
    dissipated, tunnelled or jitter)."""
    m = traj.meta
    run = RunData(traj, scene)
    out: dict[str, float | str | bool] = {
        "case": m.case,
        "engine": m.engine,
        "integrator": m.integrator,
        "dt": m.dt,
        "steps": m.steps,
        "setup_s": m.setup_s,
        "wall_s": m.wall_s,
        "steps_per_s": m.steps_per_s,
        "realtime_factor": m.duration / m.wall_s if m.wall_s > 0 else float("inf"),
        "solver_sweeps": m.solver.get("sweeps_per_solve", np.nan),
        "solver_at_limit": m.solver.get("at_limit", np.nan),
        "solver_subspace": m.solver.get("subspace_per_solve", np.nan),
        "solver_extrapolations": m.solver.get("extrapolations_per_solve", np.nan),
    }
    with np.errstate(over="ignore", invalid="ignore"):  # a blown-up run's drifts are inf
        out.update(drifts(traj, scene))
        out["energy_gain"] = energy_growth(traj, scene, run)
    if exact_trajectory_available(scene):
        times = body_arrays(traj, scene.bodies[0].name)["t"]
        errors = pose_errors(traj, exact_states(scene, times), scene)
        out["reference"] = "exact"
        out["position_error"] = float(errors["position_error"].max())
        out["orientation_error_deg"] = float(errors["orientation_error_deg"].max())
        final = errors[errors["t"] == errors["t"].max()]
        out["final_orientation_error_deg"] = float(final["orientation_error_deg"].max())
    if "shape_error" in traj.table:
        out["shape_error"] = float(traj.table["shape_error"].max())
    if scene.expected is not None and scene.expected.rest_com_height is not None:
        for body in scene.bodies:
            r = rest(traj, scene, body.name)
            prefix = "" if len(scene.bodies) == 1 else f"{body.name}."
            out[prefix + "at_rest"] = r["at_rest"]
            out[prefix + "rest_com_height"] = r["com_height"]
            out[prefix + "rest_height_error"] = r["com_height"] - scene.expected.rest_com_height
    out["engine_messages"] = message_count(m.messages)
    if m.messages:
        out["first_engine_message"] = first_message(m.messages)
    out["verdict"] = verdict(traj, scene, run)
    return out
