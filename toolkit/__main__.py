"""``python -m toolkit`` runs the ``glacimap`` command line."""

from toolkit.cli import main

main()
