"""``python -m jaxcaustics``: the same as the ``jaxcaustics`` command."""

import sys

from ._cli import main

sys.exit(main())
