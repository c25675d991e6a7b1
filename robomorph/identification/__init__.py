"""Identification: everything that estimates a robot's parameters or state from data.

The regression solve of the inverse dynamics (``regressor``, over ``stacked`` copies of the arm),
the rollout fit and its public rollout engine (``identify``), the physics backbone that simulates
identified robots over windows (``backbone``), the friction mixture of joints that held still
(``stiction``), the smoother of whole horizons and its Kalman pass (``smoother``, ``kalman``), and
the tangent-linear candidates of a planner (``tangent``). It reads the arms and their
randomization from :mod:`robomorph.sim` and nothing above it.
"""
