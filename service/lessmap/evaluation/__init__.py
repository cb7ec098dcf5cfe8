"""Evaluation of segmentations: information loss (Eq. 5), baselines, sweeps, consistency.

Modules: ``dataset`` (frames + edges + odometry as a linearized SLAM problem), ``infoloss``
(landmark information matrix and e), ``segmentation`` (LESS-mapping runs as frame labels),
``baselines``, ``sweep``, ``report`` (``evaluate``), ``simrun`` (a simulated run as a data
set: the truth read by ``lessmap.sim``, a synthesized SLAM problem), ``consistency``
(detections of each method, scored by ``lessmap.sim.groundtruth``, plus the revisit spread),
``diagnosis`` (why e comes out as it does), ``plots`` and ``charts`` (matplotlib, imported
only when figures are drawn), ``markdown`` (eval.md), ``commands`` (``lessmap eval`` and
``lessmap plot``), and ``results`` (the measured figures of docs/RESULTS.md; the page is
rendered by ``docs/results/generate.py``, outside the package).
"""
