"""Contrast maximization (Gallego and Scaramuzza, RA-L 2017): angular velocity from events
without learning, the gyroscope to use on real cameras.

Modules, each importing only those above it:

- :mod:`~spikegyro.cmax.iwe`: the image of warped events, its contrast and the exact gradient
  (Numba);
- :mod:`~spikegyro.cmax.windows`: causal window policy, event buffer, hot pixels;
- :mod:`~spikegyro.cmax.config`: :class:`~spikegyro.cmax.config.CMaxConfig`;
- :mod:`~spikegyro.cmax.problem`: events as rays (calibration, ray tables, ``Problem``);
- :mod:`~spikegyro.cmax.search`: the estimate of one window (grid search and BFGS);
- :mod:`~spikegyro.cmax.confidence`: whether one rotation explains a window (``ill_posed`` 4);
- :mod:`~spikegyro.cmax.live`: the causal estimator
  (:class:`~spikegyro.cmax.live.CMaxEstimator`, a ``GyroEstimator``);
- :mod:`~spikegyro.cmax.series`: estimates over streams in memory and evaluation windows;
- :mod:`~spikegyro.cmax.files`: intrinsics and estimators for event files;
- :mod:`~spikegyro.cmax.offline`: the offline engine over a recording (centred windows);
- :mod:`~spikegyro.cmax.commands`: ``spikegyro baseline cmax`` and ``spikegyro calibrate-imu``.
"""
