"""Non-learned baselines: mean predictor and contrast maximization."""
