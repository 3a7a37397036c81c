"""``python -m cli`` (and ``torchrun -m cli``) run the ``rgb2cloud`` command line."""

from cli.main import main

main()
