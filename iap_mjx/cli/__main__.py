"""``python -m iap_mjx.cli``: the ``iap-mjx`` command."""

import sys

from iap_mjx.cli import main

sys.exit(main())
