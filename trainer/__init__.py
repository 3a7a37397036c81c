"""The trainer: networks, losses, data readers, training, evaluation and export (PyTorch)."""
