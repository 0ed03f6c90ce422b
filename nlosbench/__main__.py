"""`python -m nlosbench`: the `nlosbench` command."""
import sys

from .cli import main

sys.exit(main())
