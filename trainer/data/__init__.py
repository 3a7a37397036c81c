"""The training dataset: a config's sources as frames (``sources``), paired transforms, and the torch dataset."""
