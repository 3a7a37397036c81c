"""The ``rgb2cloud`` command line: the trainer's commands and the service's client, each imported on use."""
