"""``python -m federation``: the ``fedlab`` command (:func:`federation.cli.main`)."""

import sys

from federation.cli import main

__all__: list[str] = []

sys.exit(main())
