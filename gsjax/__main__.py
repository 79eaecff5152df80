"""``python -m gsjax``: the ``gsjax`` command (:mod:`gsjax.app.cli`)."""

import sys

from gsjax.app.cli import main

sys.exit(main())
