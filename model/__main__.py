"""``python -m model`` (and ``torchrun -m model``) run the ``rgb2cloud`` CLI."""

from model.cli import main

main()
