"""Networks (SNN-6, ANN-6, ResNet-50), the model registry and checkpoints."""

# Importing the model modules registers "ann6", "resnet50" and "snn6".
from spikegyro.models import ann6, resnet, snn6  # noqa: F401
from spikegyro.models.official import load_official  # noqa: F401
