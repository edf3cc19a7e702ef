"""``python -m wandcal.service.cli``: the ``wandcal`` command (tests and the trigger emulator's child)."""

import sys

from wandcal.service.cli import main

sys.exit(main())
