"""`python -m truav.cli ...`: the `truav` program."""
import sys

from truav.cli.main import main

sys.exit(main())
