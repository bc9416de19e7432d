"""``python -m fitlab.cli``: the same as the ``fitlab`` command."""

import sys

from fitlab.cli import main

sys.exit(main())
