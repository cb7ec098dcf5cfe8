"""Evaluation of segmentations: information loss (Eq. 5), baselines, sweeps, consistency.

Modules: ``dataset`` (frames + edges + odometry as a linearized SLAM problem), ``infoloss``
(landmark information matrix and e), ``segmentation`` (LESS-mapping runs as frame labels),
``baselines``, ``sweep``, ``report`` (``evaluate``), ``simrun`` (a simulated run's files:
ground truth, building, synthesized SLAM problem), ``consistency`` (transitions against the
true room changes, revisit spread), ``diagnosis`` (why e comes out as it does), ``plots``
and ``charts`` (matplotlib, imported only when figures are drawn), ``markdown`` (eval.md),
``commands`` (``lessmap eval`` and ``lessmap plot``), and ``results`` with ``resultsdoc``
and ``whydoc`` (``python -m lessmap.evaluation.results``: docs/RESULTS.md).
"""
