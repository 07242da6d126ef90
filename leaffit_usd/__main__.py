import sys

from leaffit_usd.cli import main

sys.exit(main())
