"""The ``jaxcaustics`` command: `main.py` (``render``) and `design.py` (``design``)."""
