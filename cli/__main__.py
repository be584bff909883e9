"""``python -m spcodec.cli``: the ``spcodec`` command without its console script."""

import sys

from . import main

sys.exit(main())
