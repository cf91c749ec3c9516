"""``python -m v2xbench.cli ...`` is the ``v2xbench`` command."""

import sys

from v2xbench.cli import main

sys.exit(main())
