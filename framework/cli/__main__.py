"""``python -m spherecal.cli``: the ``spherecal`` program."""

import sys

from spherecal.cli import main

sys.exit(main())
