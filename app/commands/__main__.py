"""``python -m granlab.app.commands``: the ``granlab`` command."""

import sys

from . import main

sys.exit(main())
