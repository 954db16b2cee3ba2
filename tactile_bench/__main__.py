"""``python -m tactile_bench``."""

import sys

from tactile_bench.cli import main

sys.exit(main())
