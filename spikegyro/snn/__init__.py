"""SRM spiking neurons with SLAYER-style surrogate gradients."""
