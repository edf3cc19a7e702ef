"""``python -m wandcal.service.cli``: the ``wandcal`` command, as the tests and benches start it."""

import sys

from wandcal.service.cli import main

sys.exit(main())
