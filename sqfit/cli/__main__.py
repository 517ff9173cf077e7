"""``python -m sqfit.cli``: the ``sqfit`` command."""

import sys

from . import main

sys.exit(main())
