"""Dataset windows, augmentation, loss and the training loop."""
