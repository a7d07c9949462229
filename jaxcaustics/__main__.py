"""``python -m jaxcaustics``: the same as the ``jaxcaustics`` command."""

import sys

from .cli.main import main

sys.exit(main())
