"""Networks (SNN-6, ANN-6, ResNet-50), the model registry and checkpoints."""
