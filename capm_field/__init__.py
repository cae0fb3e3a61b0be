"""capm_field: the hardware-free core — robot model, camera, task constraints, reachability,
energy, probability, planners, detector, configuration and the CLI dispatcher.

It imports none of `drivers`, `mission`, `sim_bench` (DESIGN.md: dependencies point one way).
"""

__version__ = "0.1.0"
