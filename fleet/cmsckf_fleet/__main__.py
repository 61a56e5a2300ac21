"""`python -m cmsckf_fleet`: the same as the `cmsckf-fleet` command."""

import sys

from .cli import main

sys.exit(main())
