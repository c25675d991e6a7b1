"""Closed-loop model-predictive control of unseen robots with the in-context model.

``robomorph control`` runs seeded episodes on randomized robots of any registered arm
(:mod:`robomorph.sim.arms`: ``--robot``, default the model's arm or the Panda; wider
uncertainty than training by default): a warm-up under the catalogue OSC records the first context, then each
controller tracks a circle, a spiral or a point-to-point reach. Controllers: ``osc`` (the
catalogue OSC), and MPPI (:mod:`robomorph.control.mppi`) planning on the in-context model
(``mpc:model``), the catalogue robot, the identified robot or the true robot
(:mod:`robomorph.control.dynamics`).
"""

