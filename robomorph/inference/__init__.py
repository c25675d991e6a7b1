"""Inference: what a deployed model needs to predict, and nothing of training.

The :class:`~robomorph.inference.predictor.Predictor` and the checks of its inputs, the trained model
read back from its files (``checkpoint``), the hybrid (``hybrid``: identify the robot in the context,
then simulate it), its settings, its pool of workers (``hybrid_split``), its spread and std
(``hybrid_spread``, ``hybrid_std``), the regression's debiasing, the std calibration and the
physics/decoder blend stored with a model, the catalogue arm's untrained hybrid (``catalogue``), the
learned residual's prior (``residual``: the hybrid a residual model corrects), and the rolling hybrid
(``rolling``: a rolling context identified every few calls, predicted from its newest samples between).
"""
