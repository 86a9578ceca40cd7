"""Networks (SNN-6, ANN-6, ResNet-50), the model registry and checkpoints."""

from spikegyro.models import ann6, resnet  # noqa: F401  (register "ann6", "resnet50")
