"""``python -m hybridfit`` is the ``hybridfit`` command."""

import sys

from .cli import main

sys.exit(main())
