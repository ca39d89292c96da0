"""``python -m blenav COMMAND ...``: the same as the ``blenav`` command (:mod:`blenav.cli.main`)."""

import sys

from blenav.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
