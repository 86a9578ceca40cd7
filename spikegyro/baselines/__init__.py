"""Non-learned baselines: the mean predictor. Contrast maximization is :mod:`spikegyro.cmax`."""
