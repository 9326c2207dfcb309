"""``python -m ddsolve``: see :mod:`ddsolve.cli`."""
import sys

from .cli import main

sys.exit(main())
