"""``python -m photonmap``: the ``photonmap`` command."""

from .cli import main

main()
