"""``python -m app`` does what the ``sensnake`` console script does."""

import sys

from app.cli import main

sys.exit(main())
