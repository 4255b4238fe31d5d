"""The report's sections, one function each, in report order: `overview` (title, timings,
throughput, catalog), `case` (one per case), `limits` (largest stable dt, cost to reach a
tolerance), `outcomes` (contact validation), `physics` (the physics gates), `scaling`, `manifest`
(parity, machine, versions).
Each returns the section's Markdown lines."""
