"""``python -m ddsolve``: see :mod:`ddsolve.cli`."""
import sys

try:                     # Ctrl-C while the modules load (numpy, scipy: about a second): as in cli.main
    from .cli import main
except KeyboardInterrupt:
    sys.stderr.write("ddsolve: interrupted\n")
    sys.exit(130)

sys.exit(main())
