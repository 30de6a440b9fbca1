"""``python -m tl_gym.cli``: the same as the ``tl-gym`` console script."""

import sys

from .commands import main

sys.exit(main())
