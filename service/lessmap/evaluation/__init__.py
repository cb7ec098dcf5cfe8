"""Evaluation of segmentations: information loss (Eq. 5), baselines, sweeps, plots.

Modules: ``dataset`` (frames + edges + odometry as a linearized SLAM problem), ``infoloss``
(landmark information matrix and e), ``segmentation`` (LESS-mapping runs as frame labels),
``baselines``, ``sweep``, ``report`` (``evaluate``), ``plots`` (matplotlib, imported only
when figures are drawn) and ``commands`` (``lessmap eval`` and ``lessmap plot``).
"""
