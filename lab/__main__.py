"""``python -m lab`` runs the ``rgb2cloud-lab`` command line."""

from lab.cli import main

main()
